"""A run's bag, uncompressed and with zstd chunk compression: sizes and write times.

    python bench/bench_bag.py RUN_FOLDER

Reads ``RUN_FOLDER/bag`` and writes its messages twice into a temporary folder with
:class:`vigil.bag.BagWriter` (``compress=False`` and ``True``), then reads each copy back
(a check that nothing was lost). Prints the sizes, the write and read times, the bytes
per topic (raw and zstd-compressed on their own), and what the camera frames would take
as JPEG (quality 90, OpenCV): an estimate, the bag keeps raw rgb8 frames.
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from rosbags.rosbag2 import Reader

from vigil.bag import BagWriter, typestore


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def main(run: str) -> None:
    src = Path(run) / "bag"
    store = typestore()
    with Reader(src) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        msgs = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
    per_topic: dict[str, int] = defaultdict(int)
    for name, _, raw in msgs:
        per_topic[name] += len(raw)
    print(f"{src}: {_size(src) / 2**20:.1f} MiB on disk, {len(msgs)} messages")
    with tempfile.TemporaryDirectory() as tmp:
        for compress in (False, True):
            dst = Path(tmp) / f"bag-{compress}"
            t0 = time.perf_counter()
            w = BagWriter(dst, store, compress=compress)
            for name, msgtype in types.items():
                w.add_topic(name, msgtype)
            for name, t_ns, raw in msgs:
                w.write(name, t_ns, raw)
            w.close()
            write_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            with Reader(dst) as reader:
                n = sum(1 for _ in reader.messages())
            read_s = time.perf_counter() - t0
            assert n == len(msgs), (n, len(msgs))
            what = "zstd chunks" if compress else "uncompressed"
            print(
                f"{what:>13}: {_size(dst) / 2**20:6.1f} MiB, write {write_s:.2f} s, "
                f"read {read_s:.2f} s"
            )
    from backports import zstd

    for name, size in sorted(per_topic.items(), key=lambda kv: -kv[1])[:8]:
        packed = len(zstd.compress(b"".join(raw for n, _, raw in msgs if n == name)))
        print(f"  {name}: {size / 1e6:.1f} MB of messages, {packed / 1e6:.1f} MB with zstd")
    frames = [raw for n, _, raw in msgs if types.get(n) == "sensor_msgs/msg/Image"]
    if frames:
        import cv2

        jpeg = 0
        for raw in frames:
            img = store.deserialize_cdr(raw, "sensor_msgs/msg/Image")
            rgb = img.data.reshape(img.height, img.width, 3)
            ok, buf = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
            jpeg += len(buf)
        print(f"  camera frames as JPEG (quality 90): {jpeg / 1e6:.1f} MB for {len(frames)}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
