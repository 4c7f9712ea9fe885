"""Every file vigil creates or truncates is opened without following a symbolic link
(issue 23), including those its libraries and helper programs write by name: the
figures (matplotlib), the video (ffmpeg), the spoken warnings (espeak-ng), the bag
(rosbags), the keystore (openssl), and the folders it makes in a run folder.

Each test plants a link where vigil writes, pointing at a user's file or folder, and
checks that the write fails naming the link and that the user's file is unchanged
(vigil's choice: refuse, as ``stack.files.open_write`` does, rather than replace the
link). Before these writers went through ``stack.files``, each test here saw the
user's file overwritten or a file written into the user's folder."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest

from stack.cells import ConfigError
from stack.files import PrivateOutput, make_dir, replace_into, save_figure
from vigil.run_folder import fresh_run_dir

ROOT = Path(__file__).resolve().parents[1]
TASK = ROOT / "config" / "task-r1.yaml"
MINE = "years of work"


@pytest.fixture
def precious(tmp_path) -> Path:
    """A user's file, outside the run folder."""
    home = tmp_path / "home"
    home.mkdir()
    path = home / "thesis.tex"
    path.write_text(MINE)
    return path


def leftovers(folder: Path) -> list[str]:
    """What a writer left behind in ``folder``: its private ``.part`` folders."""
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".part"))


# -- the helpers -------------------------------------------------------------------------
def test_private_output_moves_the_file_into_place_and_leaves_nothing(tmp_path):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    with PrivateOutput(target) as out:
        assert out.path.name == "out.bin" and out.path.parent.parent == tmp_path
        assert stat.S_IMODE(out.path.parent.stat().st_mode) == 0o700
        out.path.write_bytes(b"new")  # as a helper program writes by name
        assert target.read_bytes() == b"old"  # nothing reaches the target before the end
    assert target.read_bytes() == b"new" and leftovers(tmp_path) == []
    # an exception: nothing reaches the target, the folder is gone
    with pytest.raises(RuntimeError), PrivateOutput(target) as out:
        out.path.write_bytes(b"half")
        raise RuntimeError("ffmpeg died")
    assert target.read_bytes() == b"new" and leftovers(tmp_path) == []


def test_private_output_refuses_a_link_at_the_target_before_and_after_the_work(tmp_path, precious):
    link = tmp_path / "camera.mp4"
    link.symlink_to(precious)
    with pytest.raises(OSError, match="symbolic link") as err:
        PrivateOutput(link)
    assert str(link) in str(err.value)
    # a link planted while the file is being written: refused at the move
    target = tmp_path / "late.mp4"
    with pytest.raises(OSError, match="symbolic link"), PrivateOutput(target) as out:
        out.path.write_bytes(b"video")
        target.symlink_to(precious)
    assert precious.read_text() == MINE and target.is_symlink()
    assert leftovers(tmp_path) == []
    with pytest.raises(OSError, match="symbolic link"):
        replace_into(tmp_path / "nothing", link)


def test_make_dir_refuses_a_link_under_the_name(tmp_path, precious):
    assert make_dir(tmp_path / "logs").is_dir()
    assert make_dir(tmp_path / "logs").is_dir()  # an existing folder is used
    (tmp_path / "speech").symlink_to(precious.parent)
    with pytest.raises(OSError, match="symbolic link") as err:
        make_dir(tmp_path / "speech")
    assert "speech" in str(err.value)
    (tmp_path / "file").write_text("x")
    with pytest.raises(NotADirectoryError):
        make_dir(tmp_path / "file")
    with pytest.raises(FileNotFoundError):  # no chain of folders made
        make_dir(tmp_path / "a" / "b")


def test_a_figure_is_never_saved_through_a_link(tmp_path, precious):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    try:
        link = tmp_path / "montecarlo.png"
        link.symlink_to(precious)
        with pytest.raises(OSError, match="symbolic link"):
            save_figure(fig, link, dpi=50)
        assert precious.read_text() == MINE
        out = save_figure(fig, tmp_path / "plain.png", dpi=50, metadata={"Software": None})
        assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert save_figure(fig, tmp_path / "fig.svg").read_text().lstrip().startswith("<?xml")
    finally:
        plt.close(fig)


# -- the run's report: figures and video ---------------------------------------------
@pytest.mark.parametrize("name", ["positions.png", "belief.png", "timeline.png", "camera.mp4"])
def test_the_report_writes_no_figure_or_video_through_a_link(tmp_path, precious, name):
    """matplotlib's savefig and ffmpeg open the name they are given and follow a link."""
    from test_report_package import make_run

    from vigil.report import write_report

    run = make_run(tmp_path / "run")
    (run / name).symlink_to(precious)
    with pytest.raises(OSError, match="symbolic link") as err:
        write_report(run, TASK)
    assert name in str(err.value)
    assert precious.read_text() == MINE and (run / name).is_symlink()
    assert leftovers(run) == []


def test_the_video_is_written_in_a_private_folder_then_moved_into_place(tmp_path, precious):
    """ffmpeg wrote ``camera.part.mp4`` by name in the run folder, then the file was
    renamed: a link planted under that name made ffmpeg overwrite the user's file. It
    now writes into a fresh 0700 folder of its own: the old name is left alone."""
    from test_report_package import make_run

    from vigil.report import write_report
    from vigil.report.video import video_codec

    run = make_run(tmp_path / "run")
    (run / "camera.part.mp4").symlink_to(precious)
    summary = write_report(run, TASK, plots=False)
    assert "camera.mp4" in summary["files"] and video_codec(run / "camera.mp4") == "h264"
    assert not (run / "camera.mp4").is_symlink()
    assert precious.read_text() == MINE and leftovers(run) == []


def test_a_video_composer_left_by_an_exception_writes_nothing(tmp_path):
    from stack.cells import CellGrid
    from vigil.report.video import VideoComposer

    path = tmp_path / "video.mp4"
    frame = np.zeros((120, 160, 3), np.uint8)
    with pytest.raises(RuntimeError, match="stop"):
        with VideoComposer(path, CellGrid(), (1,)) as video:
            video.add(0.0, frame, None, [], [0.5, 0.5, 0.0], None)
            raise RuntimeError("stop")
    assert not path.exists() and leftovers(tmp_path) == []


# -- spoken warnings -----------------------------------------------------------------------
@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="needs espeak-ng")
def test_a_spoken_warning_is_never_written_through_a_link(tmp_path, precious):
    """``espeak-ng -w FILE`` opens FILE by name and follows a link there."""
    from stack.nav.speech import synthesize

    link = tmp_path / "utterance_0001.wav"
    link.symlink_to(precious)
    with pytest.raises(OSError, match="symbolic link"):
        synthesize("Please leave.", link)
    assert precious.read_text() == MINE and leftovers(tmp_path) == []
    utt = synthesize("Please leave.", tmp_path / "utterance_0002.wav")
    assert utt.duration_s > 0.3 and utt.wav_path.read_bytes()[:4] == b"RIFF"
    assert leftovers(tmp_path) == []


# -- the bag -------------------------------------------------------------------------------
def test_a_bag_is_never_made_at_or_through_a_link(tmp_path, precious):
    from vigil.bag import BagWriter, fresh_path

    run = tmp_path / "run"
    run.mkdir()
    (run / "bag").symlink_to(precious.parent)  # a link to a user's folder
    with pytest.raises(FileExistsError, match="symbolic link"):
        BagWriter(run / "bag")
    (run / "bag_1").symlink_to(tmp_path / "nowhere")  # dangling: mkdir would refuse it too
    with pytest.raises(FileExistsError, match="symbolic link"):
        BagWriter(run / "bag_1")
    assert fresh_path(run) == run / "bag_2"  # a link, even dangling, takes the name
    assert sorted(p.name for p in precious.parent.iterdir()) == ["thesis.tex"]


@pytest.mark.parametrize("plant", ["swap the folder", "metadata.yaml.tmp", "metadata.yaml"])
def test_a_bag_writes_its_metadata_only_into_the_folder_it_made(tmp_path, precious, plant):
    """rosbags writes ``metadata.yaml.tmp`` by name at the close and renames it: a link
    planted there, or the bag folder swapped for a link to a user's folder while the
    run went on, would put the file wherever the link points."""
    from rosbags.rosbag2 import Reader

    from vigil.bag import BagWriter

    bag_dir = tmp_path / "run" / "bag"
    bag_dir.parent.mkdir()
    bag = BagWriter(bag_dir)
    bag.add_topic("/count", "std_msgs/msg/UInt32")
    for i in range(5):
        bag.write("/count", i, b"\0\1\0\0" + i.to_bytes(4, "little"))
    victim = precious.parent
    if plant == "swap the folder":
        bag_dir.rename(tmp_path / "run" / "moved")
        bag_dir.symlink_to(victim)
    else:
        (bag_dir / plant).symlink_to(precious)
    with pytest.raises(OSError, match="symbolic link|no longer the folder") as err:
        bag.close()
    assert str(bag_dir) in str(err.value)
    assert precious.read_text() == MINE
    assert sorted(p.name for p in victim.iterdir()) == ["thesis.tex"]
    bag.close()  # twice: nothing more
    # and a bag left alone is closed with its index
    ok = BagWriter(tmp_path / "run" / "bag_ok")
    ok.add_topic("/count", "std_msgs/msg/UInt32")
    ok.write("/count", 1, b"\0\1\0\0\1\0\0\0")
    ok.close()
    with Reader(tmp_path / "run" / "bag_ok") as reader:
        assert reader.message_count == 1


# -- the folders a run writes into -------------------------------------------------------
def test_a_run_folder_others_can_write_into_is_refused(tmp_path):
    """Whoever can write into the run folder can plant a link under a name vigil is
    about to write, or swap ``bag/`` or ``logs/`` for a link, between any check and the
    write; vigil's writers only refuse a link at the file's own name."""
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)
    with pytest.raises(ConfigError, match="writable by every user"):
        fresh_run_dir(shared, "r1")
    assert list(shared.iterdir()) == []
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "nowhere")
    with pytest.raises(ConfigError, match="symbolic link to nothing"):
        fresh_run_dir(dangling, "r1")
    assert not (tmp_path / "nowhere").exists()
    # a folder vigil makes is the user's, not writable by others, whatever the umask
    old = os.umask(0)
    try:
        made = fresh_run_dir(tmp_path / "new", "r1")
    finally:
        os.umask(old)
    assert stat.S_IMODE(made.stat().st_mode) == 0o755


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give a folder away")
def test_a_run_folder_of_another_user_is_refused(tmp_path):
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    os.chown(theirs, 65534, 65534)
    with pytest.raises(ConfigError, match="belongs to uid 65534"):
        fresh_run_dir(theirs, "r1")
    assert list(theirs.iterdir()) == []


def test_the_run_refuses_a_speech_folder_that_is_a_link(tmp_path, precious):
    """The speech node writes its WAVs and speech_log.tsv into ``RUN/speech``."""
    import yaml

    from vigil.deployment import parse_deployment
    from vigil.system import prepare

    (tmp_path / "policy.npz").write_bytes(b"")
    data = yaml.safe_load((ROOT / "config" / "twin.yaml").read_text())
    data.update(task=str(TASK), policy=str(tmp_path / "policy.npz"))
    data["twin"]["scene"] = str(ROOT / "config" / "twin-scene.yaml")
    dep = parse_deployment(data, tmp_path / "twin.yaml")
    run = tmp_path / "run"
    run.mkdir()
    (run / "speech").symlink_to(precious.parent)
    with pytest.raises(OSError, match="symbolic link"):
        prepare(dep, run, say=lambda s: None)
    assert sorted(p.name for p in precious.parent.iterdir()) == ["thesis.tex"]


def test_the_launcher_refuses_a_log_folder_that_is_a_link(tmp_path, precious):
    import sys

    from vigil.launch import Launcher
    from vigil.processes import ProcessSpec

    (tmp_path / "logs").symlink_to(precious.parent)
    spec = ProcessSpec("echo", "", command=[sys.executable, "-c", "print(1)"])
    launcher = Launcher([spec], tmp_path / "logs")
    with pytest.raises(OSError, match="symbolic link"):
        launcher.start()
    assert sorted(p.name for p in precious.parent.iterdir()) == ["thesis.tex"]


# -- the keystore ----------------------------------------------------------------------------
def test_the_keystore_is_written_by_openssl_without_links_or_readable_keys(tmp_path):
    """openssl writes each key, certificate and signature by name (and followed a link
    there); it now writes into a private folder and the file is moved into place, keys
    0600 from their first byte. No serial file is left beside the CA."""
    if shutil.which("openssl") is None:
        pytest.skip("needs openssl")
    from vigil.security import create_keystore

    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)
    with pytest.raises(ConfigError, match="writable by every user"):
        create_keystore(shared, domain_id=42)
    assert list(shared.iterdir()) == []
    root = tmp_path / "keystore"
    names = create_keystore(root, domain_id=42)
    assert "/vigil/velocity_gate" in names
    keys = [p for p in root.rglob("*key.pem") if not p.is_symlink()]
    assert len(keys) == len(names) + 1  # one per enclave and the CA's
    assert all(stat.S_IMODE(k.stat().st_mode) == 0o600 for k in keys)
    assert not list(root.rglob("*.srl")) and not list(root.rglob("*.part"))
    assert not list(root.rglob("req.csr"))
    serials = set()
    for name in names[:3]:
        cert = root / "enclaves" / name.strip("/") / "cert.pem"
        out = subprocess.run(
            ["openssl", "x509", "-in", str(cert), "-noout", "-serial"],
            capture_output=True, text=True, check=True,
        )  # fmt: skip
        serials.add(out.stdout.strip())
    assert len(serials) == 3  # distinct serials without a serial file
