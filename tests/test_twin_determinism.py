"""Same config and seed, same run: poses, scans, odometry and images."""

import numpy as np

from twin.config import TwinConfig
from twin.twin import Twin, VelocityCommand

CFG = TwinConfig.from_dict({"camera": {"width_px": 160, "height_px": 100}})


def _run(seed: int):
    twin = Twin(CFG, seed=seed)
    out = []
    for i in range(60):
        twin.step(VelocityCommand(0.3 * np.sin(i / 10), 0.1, 0.4 * np.cos(i / 7)))
        if i % 20 == 19:
            scan = twin.scan()
            out.append((scan.ranges_m.copy(), twin.odometry(), twin.ground_truth().robot))
    image = twin.render_camera()
    twin.close()
    return out, image, twin.data.qpos.copy()


def test_same_seed_same_run_other_seed_other_noise():
    a, img_a, q_a = _run(7)
    b, img_b, q_b = _run(7)
    c, _, q_c = _run(8)
    for (ra, oa, ga), (rb, ob, gb) in zip(a, b, strict=True):
        assert np.array_equal(ra, rb)
        assert oa == ob and ga == gb
    assert np.array_equal(img_a, img_b)
    assert np.array_equal(q_a, q_b)
    # the physics is the same, only the sensor noise differs
    assert np.array_equal(q_a, q_c)
    assert not np.array_equal(a[-1][0], c[-1][0])
    assert a[-1][1] != c[-1][1]
