"""Salvaging a bag whose writer was killed: ``vigil bag-reindex BAG``.

A bag node that is SIGKILLed (or loses its power) leaves an MCAP without its summary and
footer, cut off wherever the kill found the writer, and no ``metadata.yaml``: ``rosbags``
(and so ``vigil replay-bag``) refuses it. :func:`salvage_bag` reads the MCAP's records in
file order, as far as they are whole (schemas, channels, messages, inside chunks too:
the messages at the start of a chunk that was cut off are taken, as far as its
compressed data decodes and its records are complete), and writes the messages that
survived, in their order and with their log times, as a new bag with
:class:`vigil.bag.BagWriter`: a complete MCAP (chunk index, summary) and the same
``metadata.yaml`` as a cleanly closed bag. The message definitions are the file's own
(its schema records, registered in an empty typestore), so a bag of another vigil
version keeps its types.

The original is never written, moved or deleted: the recovered bag goes into a new
folder beside it, ``<bag>_recovered`` (``runs/x/bag`` -> ``runs/x/bag_recovered``),
which ``vigil replay-bag`` takes when ``bag/`` has no ``metadata.yaml``. (``ros2 bag
reindex`` writes a ``metadata.yaml`` into the bag folder and leaves the MCAP as it is;
``rosbags`` opens no MCAP without its footer, so a new file is needed, and the writer
never touches a path it did not create.) An existing ``<bag>_recovered`` is refused.

Hostile input: the MCAP is opened with :func:`stack.files.open_regular` without
following a link (a link, a device, a pipe or a file over :data:`MAX_BAG_BYTES` is
refused before a byte is read) and read only up to its size at the open (a writer still
running cannot make the reader endless); a record longer than :data:`MAX_RECORD_BYTES`
(a length field of 2^62, say) ends the salvage there like a cut-off one, so memory stays
bounded by one record.
"""

from __future__ import annotations

import os
import struct
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO
from zlib import crc32

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from stack.config import open_regular
from vigil.bag import BagWriter

if sys.version_info >= (3, 14):
    from compression import zstd
else:
    from backports import zstd

MAGIC = b"\x89MCAP0\r\n"
MAX_BAG_BYTES = 256 * 2**30  # far beyond any bag vigil writes (a 5.1.2 run: 13.5 MiB)
MAX_RECORD_BYTES = 256 * 2**20  # one record (a chunk, decompressed too, or a message)
RECOVERED_SUFFIX = "_recovered"
METADATA = "metadata.yaml"  # what rosbags writes on close
FEED_BYTES = 1 << 17  # compressed bytes fed to the decompressor at a time

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 1, 2, 3, 4, 5, 6
OP_DATA_END = 0x0F
OP_NAMES = (  # by opcode
    "opcode 0x00,header,footer,schema,channel,message,chunk,message index,chunk index,"
    "attachment,attachment index,statistics,metadata,metadata index,summary offset,data end"
).split(",")


class SalvageError(ValueError):
    """The path is no bag that can be salvaged (one line naming it and why)."""


def recovered_path(bag: Path) -> Path:
    """Where the salvage of ``bag`` goes: ``<bag>_recovered`` beside it."""
    bag = Path(bag)
    return bag.with_name(bag.name + RECOVERED_SUFFIX)


@dataclass
class Salvage:
    """What :func:`salvage_bag` recovered.

    Attributes:
        source: the MCAP read (unchanged).
        bag: the recovered bag's folder.
        counts: topic -> messages recovered (every topic the file declared, 0 too).
        skipped: topic -> why its messages were left out (a schema it cannot use).
        start_ns, end_ns: the first and last recovered message's log time.
        file_bytes: the MCAP's size.
        good_bytes: where its last complete record ends, what follows is lost (the
            file's size when its data-end record was found).
        stop: why reading stopped there.
        from_cut_chunk: messages taken from the start of a chunk that was cut off.
        complete: the file had its data-end record (only ``metadata.yaml`` was missing).
    """

    source: Path
    bag: Path
    counts: dict[str, int]
    skipped: dict[str, str]
    start_ns: int
    end_ns: int
    file_bytes: int
    good_bytes: int
    stop: str
    from_cut_chunk: int = 0
    complete: bool = False

    @property
    def messages(self) -> int:
        return sum(self.counts.values())

    @property
    def lost_bytes(self) -> int:
        return self.file_bytes - self.good_bytes

    def lines(self) -> list[str]:
        """The report ``vigil bag-reindex`` prints."""
        span = (self.end_ns - self.start_ns) / 1e9
        out = [
            f"recovered {self.messages} messages into {self.bag} "
            f"(log time {self.start_ns / 1e9:.3f} s to {self.end_ns / 1e9:.3f} s, {span:.3f} s)"
        ]
        width = max(len(t) for t in self.counts)
        out += [f"  {t:<{width}}  {n}" for t, n in self.counts.items()]
        out += [f"  not recovered: {t} ({why})" for t, why in self.skipped.items()]
        if self.complete:
            out.append("lost: nothing (the data was whole: its summary or metadata.yaml missing)")
        elif not self.lost_bytes:
            out.append(
                "lost: no bytes of the file (it ends after a whole record); what the writer "
                "still held in memory (its open chunk, up to about 1 MiB) never reached it"
            )
        else:
            cut = (
                f"; {self.from_cut_chunk} messages read from the start of that chunk"
                if self.from_cut_chunk
                else ""
            )
            out.append(
                f"lost: the last {self.lost_bytes} of {self.file_bytes} bytes, "
                f"from offset {self.good_bytes}: {self.stop}{cut}"
            )
        out.append(f"the original is unchanged: {self.source}")
        return out


@dataclass
class _Schema:
    name: str
    encoding: str
    data: str


@dataclass
class _Channel:
    topic: str
    schema: _Schema
    encoding: str


class _Cut(Exception):
    """Reading stops here (the reason, for the report)."""


def _string(buf: bytes | memoryview, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise _Cut("a string runs past its record")
    try:
        return bytes(buf[pos + 4 : end]).decode(), end
    except UnicodeDecodeError:
        raise _Cut("a string that is not UTF-8") from None


def _parse_schema(rec: bytes | memoryview) -> tuple[int, _Schema]:
    try:
        (sid,) = struct.unpack_from("<H", rec, 0)
        name, pos = _string(rec, 2)
        encoding, pos = _string(rec, pos)
        data, _ = _string(rec, pos)
    except struct.error:
        raise _Cut("a schema record too short") from None
    return sid, _Schema(name, encoding, data)


def _parse_channel(rec: bytes | memoryview) -> tuple[int, int, str, str]:
    try:
        cid, sid = struct.unpack_from("<HH", rec, 0)
        topic, pos = _string(rec, 4)
        encoding, _ = _string(rec, pos)
    except struct.error:
        raise _Cut("a channel record too short") from None
    return cid, sid, topic, encoding


class _Scan:
    """An MCAP's records in file order, as far as they are whole.

    Yields ``("channel", id, _Channel)`` and ``("message", channel id, log time, data)``;
    afterwards ``good_end``, ``stop``, ``from_cut_chunk`` and ``complete`` say where and
    why it stopped.
    """

    def __init__(self, f: BinaryIO, size: int, start: int):
        self.f, self.size, self.pos = f, size, start
        self.good_end = start
        self.stop = "the file ends there"
        self.from_cut_chunk = 0
        self.complete = False
        self.schemas: dict[int, _Schema] = {}
        self.channels: dict[int, _Channel] = {}

    def _read(self, n: int) -> bytes:
        n = min(n, self.size - self.pos)  # never past the size the file had at the open
        data = self.f.read(n)
        self.pos += len(data)
        return data

    def records(self) -> Iterator[tuple]:
        try:
            yield from self._top()
        except _Cut as cut:
            self.stop = str(cut)

    def _top(self) -> Iterator[tuple]:
        while self.pos < self.size:
            at = self.pos
            head = self._read(9)
            if len(head) < 9:
                raise _Cut(f"a record's opcode and length cut off ({len(head)} of 9 bytes)")
            op, length = head[0], int.from_bytes(head[1:], "little")
            what = OP_NAMES[op] if op < len(OP_NAMES) else f"opcode 0x{op:02x}"
            if op == 0 or op == OP_HEADER:
                raise _Cut(f"no MCAP record there (byte 0x{op:02x}: garbage or zeros)")
            if op in (OP_DATA_END, OP_FOOTER):  # the data is whole; the summary follows
                self.good_end, self.complete = self.size, True
                self.stop = f"the {what} record (the summary follows)"
                return
            if op not in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK):  # indexes...: skipped
                if self.pos + length > self.size:
                    raise _Cut(f"a {what} record cut off")
                self.pos = self.f.seek(self.pos + length)
                self.good_end = self.pos
                continue
            if length > MAX_RECORD_BYTES:
                raise _Cut(f"a {what} record of {length} bytes, over {MAX_RECORD_BYTES}: not read")
            if op == OP_CHUNK:
                yield from self._chunk(at, length)
                continue
            rec = self._read(length)
            if len(rec) < length:
                raise _Cut(f"a {what} record cut off ({len(rec)} of {length} bytes)")
            yield from self._record(op, rec)
            self.good_end = self.pos

    def _record(self, op: int, rec: bytes | memoryview) -> Iterator[tuple]:
        if op == OP_SCHEMA:
            sid, schema = _parse_schema(rec)
            self.schemas[sid] = schema
        elif op == OP_CHANNEL:
            cid, sid, topic, encoding = _parse_channel(rec)
            if sid not in self.schemas:
                raise _Cut(f"channel {cid} ({topic}) names schema {sid}, never declared")
            self.channels[cid] = _Channel(topic, self.schemas[sid], encoding)
            yield ("channel", cid, self.channels[cid])
        elif op == OP_MESSAGE:
            if len(rec) < 22:
                raise _Cut(f"a message record of {len(rec)} bytes, shorter than its fields")
            cid, _seq, log_time, _pub = struct.unpack_from("<HIQQ", rec, 0)
            if cid not in self.channels:
                raise _Cut(f"a message on channel {cid}, never declared")
            yield ("message", cid, log_time, bytes(rec[22:]))

    def _chunk(self, at: int, length: int) -> Iterator[tuple]:
        """A chunk's records: all of a whole chunk that checks out, else as many whole
        records from its start as its (partly present) data holds; then reading stops."""
        end = at + 9 + length
        head = self._read(32)  # start, end time, unpacked size, crc, compression's length
        if len(head) < 32 or length < 40:
            raise _Cut("a chunk record's header cut off or invalid")
        _t0, _t1, raw_size, crc, n = struct.unpack("<QQQII", head)
        name = self._read(n) if 40 + n <= length else b""
        size_field = self._read(8)
        if 40 + n > length or len(name) < n or len(size_field) < 8:
            raise _Cut("a chunk record's header cut off or invalid")
        compression = name.decode(errors="replace")
        packed = int.from_bytes(size_field, "little")
        if 40 + n + packed > length or raw_size > MAX_RECORD_BYTES:
            raise _Cut(f"a chunk at offset {at} claiming {packed} bytes ({raw_size} unpacked)")
        data, why = self._unpack(compression, packed, raw_size)
        if end <= self.size and not why:  # the whole chunk is there
            if len(data) != raw_size or (crc and crc32(data) != crc):
                raise _Cut(f"a chunk at offset {at} fails its size or checksum: corrupt")
            self.f.seek(end)  # (past any bytes after the data that a later MCAP may add)
            self.pos = end
            yield from self._inner(data, at)
            self.good_end = end
            return
        n_msgs = 0
        try:
            for item in self._inner(data, at):
                n_msgs += item[0] == "message"
                yield item
        except _Cut:
            pass
        self.from_cut_chunk = n_msgs
        raise _Cut(f"a chunk {why or 'cut off'} (it starts at offset {at})")

    def _unpack(self, compression: str, packed: int, raw_size: int) -> tuple[bytes, str]:
        """What decodes of the chunk's data (as much as is present), and "" or why not all."""
        if compression == "":
            return self._read(packed)[:raw_size], ""
        if compression not in ("zstd", "lz4"):
            raise _Cut(f"a chunk compressed with {compression!r}, which vigil cannot read")
        if compression == "zstd":
            dec = zstd.ZstdDecompressor()
        else:
            from lz4.frame import LZ4FrameDecompressor

            dec = LZ4FrameDecompressor()
        out: list[bytes] = []
        left, got = packed, 0
        while left > 0:
            piece = self._read(min(left, FEED_BYTES))
            if not piece:
                break
            left -= len(piece)
            try:
                out.append(dec.decompress(piece, max_length=raw_size - got))
            except Exception as err:  # ZstdError, lz4's RuntimeError: corrupt data
                return b"".join(out), f"whose data is corrupt ({err})"
            got += len(out[-1])
        return b"".join(out), ""

    def _inner(self, data: bytes, at: int) -> Iterator[tuple]:
        view, pos = memoryview(data), 0
        while pos < len(view):
            if pos + 9 > len(view):
                raise _Cut("a record inside a chunk cut off")
            op, length = view[pos], int.from_bytes(view[pos + 1 : pos + 9], "little")
            if op in (0, OP_HEADER, OP_CHUNK, OP_DATA_END, OP_FOOTER):
                raise _Cut(f"a chunk at offset {at} holds an invalid record (0x{op:02x})")
            if pos + 9 + length > len(view):
                raise _Cut("a record inside a chunk cut off")
            yield from self._record(op, view[pos + 9 : pos + 9 + length])
            pos += 9 + length


def closed_cleanly(bag: Path) -> bool:
    """The bag folder has its ``metadata.yaml`` (its writer closed it)."""
    return (Path(bag) / METADATA).is_file()


def find_mcap(bag: Path) -> Path:
    """The bag folder's one MCAP file, or :class:`SalvageError` saying why not."""
    if not os.path.lexists(bag):
        raise SalvageError(f"{bag}: no such bag folder")
    if not bag.is_dir():
        hint = " (give the folder that holds it)" if bag.suffix == ".mcap" else ""
        raise SalvageError(f"{bag}: not a bag folder{hint}: a bag is a folder with an .mcap file")
    found = sorted(bag.glob("*.mcap"))
    if not found:
        raise SalvageError(f"{bag}: not a bag: it holds no .mcap file")
    if len(found) > 1:
        names = ", ".join(p.name for p in found)
        raise SalvageError(f"{bag} holds {len(found)} MCAP files ({names}); vigil's bags have one")
    return found[0]


def _open(mcap: Path, max_bytes: int) -> tuple[BinaryIO, int]:
    """The MCAP opened (no link, device or pipe; at most ``max_bytes``) and its size."""
    try:
        f = open_regular(mcap, max_bytes, follow_links=False)
    except OSError as err:
        raise SalvageError(f"{mcap}: {err.strerror or err}") from None
    except ValueError as err:
        raise SalvageError(str(err)) from None
    return f, os.fstat(f.fileno()).st_size


def _header_end(f: BinaryIO, mcap: Path, size: int) -> int:
    """Checks the magic and the ros2 header record; returns where the records start."""
    if size == 0:
        raise SalvageError(
            f"{mcap} is empty (the writer was killed before it wrote a byte): nothing to recover"
        )
    head = f.read(17)  # the magic, the header record's opcode and length
    if head[:8] != MAGIC[: len(head)][:8] or head[8:9] not in (b"", bytes([OP_HEADER])):
        raise SalvageError(f"{mcap}: not an MCAP file (it does not start with MCAP's magic)")
    length = int.from_bytes(head[9:17], "little") if len(head) == 17 else size
    if 17 + length > size:
        raise SalvageError(
            f"{mcap}: an MCAP cut off in its header ({size} bytes): nothing to recover"
        )
    try:
        profile, _ = _string(f.read(min(length, 4096)), 0)
    except (struct.error, _Cut):
        raise SalvageError(f"{mcap}: an MCAP whose header record is invalid") from None
    if profile != "ros2":
        raise SalvageError(f"{mcap}: an MCAP file of profile {profile!r}, not a rosbag2 bag")
    f.seek(17 + length)
    return 17 + length


def salvage_bag(bag: str | Path, max_bytes: int | None = None) -> Salvage:
    """Recover what a bag killed mid-write holds into ``<bag>_recovered`` (module doc).

    Raises:
        SalvageError: ``bag`` is no bag folder, its MCAP is a link, a device, a pipe,
            too large or no rosbag2 MCAP, it holds no complete message, or
            ``<bag>_recovered`` exists.
    """
    bag = Path(bag)
    mcap = find_mcap(bag)
    dst = recovered_path(bag)
    if os.path.lexists(dst):
        raise SalvageError(f"{dst} exists: not overwriting it (move it away to salvage again)")
    f, size = _open(mcap, MAX_BAG_BYTES if max_bytes is None else max_bytes)
    with f:
        scan = _Scan(f, size, _header_end(f, mcap, size))
        store = get_typestore(Stores.EMPTY)  # the file's own message definitions
        writer: BagWriter | None = None
        pending: list[_Channel] = []  # channels declared before the first message
        topics: dict[int, str] = {}  # channel id -> topic recovered
        types: dict[str, str] = {}  # topic -> its type
        counts: dict[str, int] = {}
        skipped: dict[str, str] = {}
        t0, t1 = 2**64, -1
        try:
            for item in scan.records():
                if item[0] == "channel":
                    _, cid, channel = item
                    known = types.get(channel.topic)
                    why = _declare(store, channel) if known is None else ""
                    if known is not None and known != channel.schema.name:
                        why = f"a second channel of type {channel.schema.name}, not {known}"
                    if why:
                        skipped[f"{channel.topic} (channel {cid})"] = why
                        continue
                    topics[cid] = channel.topic
                    if known is not None:  # the same topic and type again: one topic
                        continue
                    types[channel.topic] = channel.schema.name
                    counts[channel.topic] = 0
                    if writer is None:
                        pending.append(channel)
                    else:
                        writer.add_topic(channel.topic, channel.schema.name)
                    continue
                _, cid, t_ns, data = item
                if cid not in topics:
                    continue  # a topic left out (its schema, named in ``skipped``)
                if writer is None:
                    writer = BagWriter(dst, store)
                    for channel in pending:
                        writer.add_topic(channel.topic, channel.schema.name)
                writer.write(topics[cid], t_ns, data)
                counts[topics[cid]] += 1
                t0, t1 = min(t0, t_ns), max(t1, t_ns)
            if writer is None:
                raise SalvageError(
                    f"{mcap} holds no complete message ({size} bytes; reading stopped at "
                    f"offset {scan.good_end}: {scan.stop}): nothing to recover"
                )
            writer.close()
        except BaseException:
            if writer is not None:  # a partial bag of our own is no salvage: removed
                writer.discard()
            raise
    return Salvage(
        mcap,
        dst,
        counts,
        skipped,
        t0,
        t1,
        size,
        scan.good_end,
        scan.stop,
        scan.from_cut_chunk,
        scan.complete,
    )


def _declare(store: Typestore, channel: _Channel) -> str:
    """Registers the channel's schema in ``store``; "" or why its topic is left out."""
    schema = channel.schema
    if channel.encoding != "cdr":
        return f"message encoding {channel.encoding!r}, not cdr"
    if schema.encoding != "ros2msg":
        return f"schema encoding {schema.encoding!r}: only ros2msg schemas are read"
    try:
        store.register(get_types_from_msg(schema.data, schema.name))
    except Exception as err:  # rosbags' TypesysError, a parse error: the schema is unusable
        return f"schema {schema.name} cannot be used: {' '.join(str(err).split())}"
    return ""
