"""SARSOP's ``.policy`` XML: alpha vectors with their actions, read and written.

The format (APPL's ``policyx.xsd``)::

    <?xml version="1.0" encoding="ISO-8859-1"?>
    <Policy version="0.1" type="value" model="Tiger.pomdp" ...>
    <AlphaVector vectorLength="2" numObsValue="1" numVectors="5">
    <Vector action="1" obsValue="0">-81.5975 28.4025 </Vector>
    ...
    </AlphaVector> </Policy>

``obsValue`` is the value of the fully observed state variable of a factored
``.pomdpx`` model (0 for a ``.pomdp`` file); a vector then covers only the states
with that value. For a flat model every vector has ``obsValue="0"``; a policy with
several observed values is expanded to flat vectors by :func:`read_policy_xml` when
told how many states share each value (``obs_blocks``). SARSOP's ``pomdpsim`` and
``pomdpeval`` read what :func:`write_policy_xml` writes.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from stack.planning.policy import AlphaPolicy, PolicyFileError

MAX_POLICY_BYTES = 1024 * 1024 * 1024


def write_policy_xml(policy: AlphaPolicy, path: str | os.PathLike, model: str = "") -> Path:
    """Write ``policy`` as SARSOP XML at exactly ``path``.

    Raises:
        ValueError: a vector holds a non-finite value (SARSOP could not read it back).
    """
    if not np.all(np.isfinite(policy.alphas)):
        raise ValueError("the policy holds non-finite values; refusing to write it")
    path = Path(path)
    K, S = policy.alphas.shape
    lines = [
        '<?xml version="1.0" encoding="ISO-8859-1"?>',
        f'<Policy version="0.1" type="value" model="{_attr(model)}" '
        'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        'xsi:noNamespaceSchemaLocation="policyx.xsd">',
        f'<AlphaVector vectorLength="{S}" numObsValue="1" numVectors="{K}">',
    ]
    for alpha, a in zip(policy.alphas, policy.actions, strict=True):
        values = " ".join(map(repr, alpha.tolist()))  # shortest round-trip text
        lines.append(f'<Vector action="{int(a)}" obsValue="0">{values} </Vector>')
    lines.append("</AlphaVector> </Policy>")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="ascii")
    tmp.replace(path)
    return path


def _attr(text: str) -> str:
    return text.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")


def is_policy_xml(path: str | os.PathLike) -> bool:
    """True when the file starts like an XML document."""
    try:
        with open(path, "rb") as f:
            head = f.read(64).lstrip()
    except OSError:
        return False
    return head.startswith(b"<?xml") or head.startswith(b"<Policy")


def read_policy_xml(
    path: str | os.PathLike,
    n_states: int | None = None,
    obs_blocks: list[np.ndarray] | None = None,
) -> AlphaPolicy:
    """Read a SARSOP ``.policy`` file.

    Args:
        path: the file.
        n_states: the model's state count, checked against the vectors.
        obs_blocks: for a factored model, the flat state indices of each value of
            the fully observed variable (vector ``obsValue=x`` covers
            ``obs_blocks[x]``; other states get -inf, so the vector never wins there).

    Raises:
        PolicyFileError: not a policy file, or vectors that do not fit the model.
    """
    path = Path(path)
    if path.is_dir():
        raise PolicyFileError(f"{path} is a directory, not a policy file")
    with open(path, "rb") as f:
        data = f.read(MAX_POLICY_BYTES + 1)
    if len(data) > MAX_POLICY_BYTES:
        raise PolicyFileError(f"{path}: larger than {MAX_POLICY_BYTES:,} bytes")
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise PolicyFileError(f"{path}: not a SARSOP policy file ({exc})") from None
    av = root if root.tag == "AlphaVector" else root.find("AlphaVector")
    if av is None:
        raise PolicyFileError(f"{path}: no <AlphaVector> element")
    try:
        length = int(av.get("vectorLength", "0"))
        vectors, actions, obs = [], [], []
        for v in av.findall("Vector"):
            vals = np.array(v.text.split(), dtype=float) if v.text else np.empty(0)
            if vals.size != length:
                raise PolicyFileError(
                    f"{path}: a vector has {vals.size} values, vectorLength says {length}"
                )
            vectors.append(vals)
            actions.append(int(v.get("action")))
            obs.append(int(v.get("obsValue", "0")))
    except (TypeError, ValueError) as exc:
        if isinstance(exc, PolicyFileError):
            raise
        raise PolicyFileError(f"{path}: bad vector ({exc})") from None
    if not vectors:
        raise PolicyFileError(f"{path}: the policy has no vectors")
    alphas = np.vstack(vectors)
    if not np.all(np.isfinite(alphas)):
        raise PolicyFileError(f"{path}: the policy holds non-finite values")
    if obs_blocks is not None:
        S = sum(len(b) for b in obs_blocks)
        flat = np.full((len(vectors), S), -np.inf)
        for k, (x, vals) in enumerate(zip(obs, vectors, strict=True)):
            if not 0 <= x < len(obs_blocks) or len(obs_blocks[x]) != vals.size:
                raise PolicyFileError(f"{path}: vector {k} does not fit observed value {x}")
            flat[k, obs_blocks[x]] = vals
        alphas = flat
    elif any(x != 0 for x in obs):
        raise PolicyFileError(
            f"{path}: vectors for several observed values (a factored .pomdpx policy); "
            "evaluate it on its .pomdpx model"
        )
    if n_states is not None and alphas.shape[1] != n_states:
        raise PolicyFileError(
            f"{path}: policy is for {alphas.shape[1]} states, the model has {n_states}"
        )
    meta = {"solver": "sarsop-xml", "model": root.get("model", ""), "file": str(path)}
    return AlphaPolicy(alphas=alphas, actions=np.asarray(actions, dtype=int), meta=meta)
