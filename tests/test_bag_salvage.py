"""``vigil bag-reindex``: a bag whose writer was killed (no summary, no metadata.yaml, cut
off anywhere) gives back exactly its complete messages in a new bag; hostile paths get a
one-line error; the original is never changed."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.rosbag2.storage_mcap import McapReader

import stack.topics as topic
import vigil.bag_salvage as salvage_mod
from stack.config import open_regular
from vigil.bag import BagWriter, read_recording, typestore
from vigil.bag_salvage import SalvageError, recovered_path, salvage_bag
from vigil.cli import main
from vigil.replay_bag import ReplayError, find_bag

REPO = Path(__file__).resolve().parents[1]
STORE = typestore()
STRING = "std_msgs/msg/String"
CLOCK = "rosgraph_msgs/msg/Clock"
TOPICS = {topic.LOCKSTEP_TICK: CLOCK, topic.PERSON: STRING}


def _string(text: str) -> bytes:
    return bytes(STORE.serialize_cdr(STORE.types[STRING](data=text), STRING))


def _clock(t_ns: int) -> bytes:
    Time = STORE.types["builtin_interfaces/msg/Time"]
    msg = STORE.types[CLOCK](clock=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9))
    return bytes(STORE.serialize_cdr(msg, CLOCK))


def _messages(n: int, pad: int = 0) -> list[tuple[str, int, bytes]]:
    """A lock-step-like stream: a tick, then a person message, each 0.04 s apart."""
    out = []
    for i in range(n):
        t = 10**9 + i * 40_000_000
        if i % 2 == 0:
            out.append((topic.LOCKSTEP_TICK, t, _clock(t)))
        else:  # unique, and hard to compress when padded (chunks fill up)
            noise = "".join(hashlib.sha256(f"{i}.{j}".encode()).hexdigest() for j in range(pad))
            out.append((topic.PERSON, t, _string(f"message {i:05d} {noise}")))
    return out


def _write(path: Path, msgs, compress: bool) -> Path:
    w = BagWriter(path, STORE, compress=compress)
    for name, msgtype in TOPICS.items():
        w.add_topic(name, msgtype)
    for name, t, cdr in msgs:
        w.write(name, t, cdr)
    w.close()
    return path / f"{path.name}.mcap"


def _killed(tmp_path: Path, data: bytes, name: str = "bag") -> Path:
    """A bag folder as a killed writer leaves it: the MCAP's first bytes, no metadata."""
    bag = tmp_path / "run" / name
    bag.mkdir(parents=True)
    (bag / f"{name}.mcap").write_bytes(data)
    return bag


def _read(bag: Path) -> list[tuple[str, int, bytes]]:
    with Reader(bag) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


CUTS = (
    "header only",
    "chunk header",
    "before the first message",
    "mid-message",
    "after 12 messages",
    "mid-last-message",
    "in the summary",
)


@pytest.mark.parametrize("cut_name", CUTS)
def test_a_cut_bag_gives_back_exactly_its_complete_messages(tmp_path, cut_name):
    # uncompressed chunks: every message's last byte has a known offset in the file
    msgs = _messages(40)
    data = _write(tmp_path / "clean" / "bag", msgs, compress=False).read_bytes()
    ends = [data.index(cdr) + len(cdr) for _, _, cdr in msgs]
    first = ends[0] - len(msgs[0][2]) - 31  # the first message record's opcode
    header_end = 17 + int.from_bytes(data[9:17], "little")
    cut = {
        "header only": header_end,
        "chunk header": header_end + 20,
        "before the first message": first,
        "mid-message": ends[6] - 5,
        "after 12 messages": ends[11],
        "mid-last-message": ends[-1] - 1,
        "in the summary": len(data) - 30,
    }[cut_name]
    expected = [m for m, end in zip(msgs, ends, strict=True) if end <= cut]
    bag = _killed(tmp_path, data[:cut])
    original = bag / "bag.mcap"
    before = _digest(original)
    if not expected:
        with pytest.raises(SalvageError, match="nothing to recover"):
            salvage_bag(bag)
        assert not recovered_path(bag).exists()
    else:
        result = salvage_bag(bag)
        assert result.bag == tmp_path / "run" / "bag_recovered"
        assert _read(result.bag) == expected  # the prefix, in order, byte for byte
        counts = {t: sum(m[0] == t for m in expected) for t in TOPICS}
        assert result.counts == counts and result.messages == len(expected)
        assert (result.start_ns, result.end_ns) == (expected[0][1], expected[-1][1])
        assert result.file_bytes == cut
        if cut_name == "in the summary":
            assert result.complete and result.lost_bytes == 0
        else:  # the one chunk was cut off: its messages read from its start
            assert result.from_cut_chunk == len(expected)
            assert result.good_bytes == header_end and result.lost_bytes == cut - header_end
        # the same metadata.yaml as the writer's own for those messages (file names aside)
        ref = tmp_path / "ref" / "bag_recovered"
        _write(ref, expected, compress=True)
        meta = yaml.safe_load((result.bag / "metadata.yaml").read_text())
        assert meta == yaml.safe_load((ref / "metadata.yaml").read_text())
        with Reader(result.bag) as got, Reader(tmp_path / "clean" / "bag") as clean:
            assert [(c.topic, c.msgtype, c.msgdef.data, c.digest) for c in got.connections] == [
                (c.topic, c.msgtype, c.msgdef.data, c.digest) for c in clean.connections
            ]
    assert _digest(original) == before  # the original is never changed
    assert sorted(p.name for p in bag.iterdir()) == ["bag.mcap"]


def _chunks(mcap: Path) -> list[tuple[int, int, int]]:
    """Per chunk of a whole MCAP: its start offset, its end and its message count."""
    reader = McapReader(mcap)
    reader.open()
    try:
        return [
            (
                c.chunk_start_offset,
                c.chunk_start_offset + c.chunk_length,
                sum(c.channel_count.values()),
            )
            for c in reader.chunks
        ]
    finally:
        reader.close()


def test_a_compressed_bag_keeps_its_whole_chunks_and_what_decodes_of_a_cut_one(tmp_path):
    msgs = _messages(1000, pad=100)  # 6.4 kB a person message: several 1 MiB chunks
    mcap = _write(tmp_path / "clean" / "bag", msgs, compress=True)
    data = mcap.read_bytes()
    chunks = _chunks(mcap)
    assert len(chunks) >= 3
    before = sum(n for _, _, n in chunks[:2])
    start, end, n = chunks[2]
    for i, cut in enumerate((start, start + 30)):  # the third chunk absent, or its header cut
        result = salvage_bag(_killed(tmp_path / f"c{i}", data[:cut]))
        assert _read(result.bag) == msgs[:before]
        assert result.good_bytes == start and result.lost_bytes == cut - start
    # its compressed data cut in the middle: the messages of its whole zstd blocks, no more
    result = salvage_bag(_killed(tmp_path / "mid", data[: (start + end) // 2]))
    got = _read(result.bag)
    assert before < len(got) < before + n and got == msgs[: len(got)]
    assert result.from_cut_chunk == len(got) - before


@pytest.mark.parametrize("tail", ["zeros", "endless record"])
def test_garbage_after_the_last_whole_chunk_ends_the_salvage_there(tmp_path, tail):
    """A power cut can leave zeros; a hostile length field must not be allocated."""
    msgs = _messages(1000, pad=100)
    mcap = _write(tmp_path / "clean" / "bag", msgs, compress=True)
    start, _, _ = _chunks(mcap)[1]
    extra = bytes(4096) if tail == "zeros" else b"\x05" + (2**62).to_bytes(8, "little") + b"x" * 64
    result = salvage_bag(_killed(tmp_path, mcap.read_bytes()[:start] + extra))
    assert _read(result.bag) == msgs[: _chunks(mcap)[0][2]]
    assert result.lost_bytes == len(extra)
    assert ("zeros" if tail == "zeros" else "over") in result.stop


KILLED_WRITER = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, sys.argv[2])
    from pathlib import Path
    from tests.test_bag_salvage import STORE, TOPICS, _messages
    from vigil.bag import BagWriter

    w = BagWriter(Path(sys.argv[1]), STORE)  # as the bag node: zstd chunks
    for name, msgtype in TOPICS.items():
        w.add_topic(name, msgtype)
    msgs = _messages(4000, pad=32)
    for i, (name, t, cdr) in enumerate(msgs):
        w.write(name, t, cdr)
        if i == 3000:
            print("written", flush=True)
    print("done", flush=True)
    sys.stdin.read()  # until SIGKILLed: the last chunk is still in memory
    """
)


def test_a_writer_killed_mid_run_leaves_a_bag_whose_complete_prefix_is_salvaged(tmp_path):
    bag = tmp_path / "run" / "bag"
    bag.parent.mkdir()
    child = subprocess.Popen(
        [sys.executable, "-c", KILLED_WRITER, str(bag), str(REPO)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    try:
        assert child.stdout is not None and child.stdout.readline() == "written\n"
        child.send_signal(signal.SIGKILL)
    finally:
        child.kill()
        child.wait(30)
    assert child.returncode == -signal.SIGKILL
    assert not (bag / "metadata.yaml").exists()  # what a SIGKILL leaves
    with pytest.raises(ReaderError, match="magic"):  # no footer: rosbags cannot read it
        McapReader(bag / "bag.mcap").open()
    before = _digest(bag / "bag.mcap")
    result = salvage_bag(bag)
    got = _read(result.bag)
    msgs = _messages(4000, pad=32)
    assert 0 < len(got) <= 3001 and got == msgs[: len(got)]
    assert result.messages == len(got)
    assert _digest(bag / "bag.mcap") == before


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["bag-reindex", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_bag_reindex_prints_what_it_recovered_and_refuses_to_do_it_twice(tmp_path, capsys):
    msgs = _messages(40)
    data = _write(tmp_path / "clean" / "bag", msgs, compress=False).read_bytes()
    cut = data.index(msgs[21][2]) + len(msgs[21][2])  # after 22 messages
    bag = _killed(tmp_path, data[:cut])
    code, out, err = _cli(capsys, str(bag))
    assert code == 0 and err == ""
    assert f"recovered 22 messages into {bag}_recovered" in out
    assert "log time 1.000 s to 1.840 s, 0.840 s" in out
    assert "/lockstep/tick      11" in out and "/perception/person  11" in out
    assert f"lost: the last {cut - 43} of {cut} bytes, from offset 43: a chunk cut off" in out
    assert "22 messages read from the start of that chunk" in out
    assert f"the original is unchanged: {bag / 'bag.mcap'}" in out
    recovered = bag.with_name("bag_recovered")
    first = _digest(recovered / "bag_recovered.mcap")
    code, out, err = _cli(capsys, str(bag))  # again: the recovered bag is never overwritten
    assert code == 2 and "exists: not overwriting it" in err and err.count("\n") == 1
    assert _digest(recovered / "bag_recovered.mcap") == first
    code, out, err = _cli(capsys, str(recovered))  # a closed bag: nothing to do
    assert code == 0 and "closed cleanly, nothing to salvage" in out
    assert not recovered.with_name("bag_recovered_recovered").exists()


def _hostile(tmp_path: Path, case: str) -> Path:
    """The BAG argument for one hostile case."""
    real = _write(tmp_path / "clean" / "bag", _messages(10), compress=False)
    bag = tmp_path / "run" / "bag"
    bag.mkdir(parents=True)
    mcap = bag / "bag.mcap"
    if case == "missing":
        return tmp_path / "nowhere"
    if case == "a file":
        mcap.write_bytes(real.read_bytes()[:200])
        return mcap
    if case == "/dev/zero":
        return Path("/dev/zero")
    if case == "no mcap":
        (bag / "notes.txt").write_text("a folder of mine")
    elif case == "not MCAP":
        mcap.write_text("rosbag2_bagfile_information: {}\n" * 10)
    elif case == "empty":
        mcap.touch()
    elif case == "a link to a bag":
        mcap.symlink_to(real)
    elif case == "a link to /dev/zero":
        mcap.symlink_to("/dev/zero")
    elif case == "a pipe":
        os.mkfifo(mcap)
    elif case == "huge":
        mcap.write_bytes(real.read_bytes()[:300])
    elif case == "another profile":
        mcap.write_bytes(real.read_bytes()[:8] + b"\x01" + (8).to_bytes(8, "little") + bytes(8))
    elif case == "two MCAPs":
        mcap.write_bytes(real.read_bytes()[:300])
        (bag / "bag_1.mcap").write_bytes(real.read_bytes()[:300])
    elif case == "taken":
        mcap.write_bytes(real.read_bytes()[:300])
        (tmp_path / "run" / "bag_recovered").mkdir()
        (tmp_path / "run" / "bag_recovered" / "mine.txt").write_text("keep")
    return bag


HOSTILE = {
    "missing": "no such bag folder",
    "a file": "not a bag folder (give the folder that holds it)",
    "/dev/zero": "not a bag folder",
    "no mcap": "holds no .mcap file",
    "not MCAP": "not an MCAP file",
    "empty": "is empty",
    "a link to a bag": "is a symbolic link: not read",
    "a link to /dev/zero": "is a symbolic link: not read",
    "a pipe": "not a regular file",
    "huge": "longer than 100 bytes",
    "another profile": "not a rosbag2 bag",
    "two MCAPs": "holds 2 MCAP files",
    "taken": "exists: not overwriting it",
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_a_hostile_bag_is_refused_in_one_line(tmp_path, capsys, monkeypatch, case):
    if case == "huge":  # a file over the cap (256 GiB by default) is refused by its size
        monkeypatch.setattr(salvage_mod, "MAX_BAG_BYTES", 100)
    bag = _hostile(tmp_path, case)
    files = {p: (p.is_symlink(), p.is_file() and _digest(p)) for p in tmp_path.rglob("*")}
    code, out, err = _cli(capsys, str(bag))
    assert code == 2, out
    assert err.startswith("vigil bag-reindex: error: ") and err.count("\n") == 1, err
    assert HOSTILE[case] in err
    # nothing written, nothing changed: the same files with the same bytes
    assert {p: (p.is_symlink(), p.is_file() and _digest(p)) for p in tmp_path.rglob("*")} == files


def test_open_regular_can_refuse_a_link(tmp_path):
    target = tmp_path / "real.mcap"
    target.write_bytes(b"x")
    (tmp_path / "link.mcap").symlink_to(target)
    with open_regular(tmp_path / "link.mcap") as f:  # followed by default, as before
        assert f.read() == b"x"
    with pytest.raises(OSError, match="symbolic link"):
        open_regular(tmp_path / "link.mcap", follow_links=False)


def test_replay_bag_names_the_salvage_and_then_replays_the_recovered_bag(tmp_path, capsys):
    msgs = _messages(40)
    data = _write(tmp_path / "clean" / "bag", msgs, compress=False).read_bytes()
    cut = data.index(msgs[24][2]) + len(msgs[24][2])  # 25 messages: 13 ticks
    bag = _killed(tmp_path, data[:cut])
    with pytest.raises(ReplayError, match=f"not closed.*`vigil bag-reindex {bag}`"):
        find_bag(tmp_path / "run")
    assert main(["bag-reindex", str(bag)]) == 0
    assert find_bag(tmp_path / "run") == tmp_path / "run" / "bag_recovered"
    recording = read_recording(find_bag(tmp_path / "run"))
    assert [t.t_ns for t in recording.ticks] == [
        t for name, t, _ in msgs[:25] if name == topic.LOCKSTEP_TICK
    ]
    assert recording.count(topic.PERSON) == 12


def test_a_salvage_that_fails_midway_leaves_no_partial_bag(tmp_path, capsys, monkeypatch):
    msgs = _messages(40)
    data = _write(tmp_path / "clean" / "bag", msgs, compress=False).read_bytes()
    bag = _killed(tmp_path, data[: len(data) // 2])
    before = _digest(bag / "bag.mcap")
    written = []

    def full_disk(self, name, t_ns, cdr):
        if len(written) == 5:
            raise OSError(28, "No space left on device")
        written.append(t_ns)

    monkeypatch.setattr(BagWriter, "write", full_disk)
    code, out, err = _cli(capsys, str(bag))
    assert code == 2 and "No space left on device" in err and err.count("\n") == 1
    assert not recovered_path(bag).exists()  # its own partial folder removed
    assert _digest(bag / "bag.mcap") == before
