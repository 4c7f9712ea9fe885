"""``vigil fit-perception``: fit the camera pipeline's model to rendered runs.

Rendered in-process runs (``vigil montecarlo --perception rendered``) write, per camera
frame, the truth and what HOG and the homography detected (``detections.jsonl``). This
command reads every such file under the folders it is given, fits
:class:`stack.perception.model.PerceptionModel` and writes it with the fit's data,
date and command in ``meta``; with ``--episodes N`` it first runs N rendered
random-walk episodes to fit on.
"""

from __future__ import annotations

import json
import shlex
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from stack.cells import ConfigError
from stack.files import MAX_RECORD_BYTES, read_text_capped
from stack.perception.model import (
    DETECTIONS_FILE,
    FrameRecord,
    PerceptionModel,
    fit,
    frame_record,
)


def read_frames(folders: Sequence[Path]) -> tuple[list[FrameRecord], list[Path]]:
    """Every frame record under ``folders`` (one episode per ``detections.jsonl``)."""
    frames: list[FrameRecord] = []
    files = sorted(f for d in folders for f in Path(d).rglob(DETECTIONS_FILE))
    for f in files:
        episode = str(f.parent)
        for n, line in enumerate(read_text_capped(f, MAX_RECORD_BYTES).splitlines(), start=1):
            if not line.strip():
                continue
            try:
                frames.append(frame_record(json.loads(line), episode))
            except (ValueError, KeyError, TypeError, IndexError) as err:
                raise ConfigError(f"{f}:{n}", line[:60], f"not a frame record: {err}") from None
    return frames, files


def visibility_of_run(run_dir: Path):
    """The camera visibility the run's observation node had (its calibration and grid)."""
    from stack.perception.config import load_config_file
    from stack.perception.homography import load_calibration
    from stack.perception.visibility import CameraVisibility, VisibilityConfig

    grid, sections = load_config_file(run_dir / "stack.yaml")
    homography = load_calibration(run_dir / "calibration.yaml").homography
    return CameraVisibility(
        homography, grid, VisibilityConfig.from_dict(sections.get("visibility"))
    )


def fit_folders(
    folders: Sequence[Path], output: Path, say: Callable[[str], None] = print
) -> tuple[PerceptionModel, dict[str, Any]]:
    """Fit on every rendered run under ``folders``; write the model to ``output``."""
    frames, files = read_frames(folders)
    if not files:
        raise ConfigError("folders", [str(f) for f in folders], f"hold no {DETECTIONS_FILE}")
    say(f"[fit-perception] {len(frames)} frames from {len(files)} rendered runs")
    meta = {
        "runs": len(files),
        "sources": sorted({str(Path(f).parent.parent) for f in files}),
        "command": "vigil " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
    }
    model, report = fit(frames, visibility_of_run(files[0].parent), meta)
    model = PerceptionModel(**{**model.__dict__, "meta": {**model.meta, "fit": report}})
    model.save(output)
    say(
        f"[fit-perception] detection rate {report['detection_rate']:.3f}, position error "
        f"mean {report['error_mean_m']} m, sd {report['error_sd_m']} m, rho "
        f"{report['error_rho']}, {report['false_per_frame']} false positives per frame"
    )
    for row in report["calibration"]:
        say(
            f"[fit-perception]   p_model {row['p_model'][0]:.2f}-{row['p_model'][1]:.2f}: "
            f"{row['n']} person-frames, model {row['mean_model']:.3f}, data {row['rate_data']:.3f}"
        )
    say(f"[fit-perception] wrote {output}")
    return model, report
