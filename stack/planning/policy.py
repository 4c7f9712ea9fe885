"""An alpha-vector policy: V(b) = max_k alpha_k . b, action of the maximising vector."""

from __future__ import annotations

import json
import os
import tokenize
import xml.etree.ElementTree as ET
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stack.config import open_regular, open_write, read_bytes_capped
from stack.planning import clock


class PolicyFileError(ValueError):
    """A policy file that cannot be read or does not fit the model."""


# what numpy's reader of a truncated or mutated .npz raises: zip-level errors, zlib's,
# the .npy header parser's (tokenize, ast) and a zip feature it does not implement
CORRUPT_ARCHIVE_ERRORS = (
    OSError,
    KeyError,
    ValueError,
    EOFError,
    zipfile.BadZipFile,
    zlib.error,
    NotImplementedError,
    SyntaxError,
    tokenize.TokenError,
)


@dataclass(frozen=True, eq=False)
class AlphaPolicy:
    """Alpha vectors (K, S) with their actions (K,), or per observed block.

    Attributes:
        alphas: one row per vector: over the flat states, or with ``blocks`` over the
            states of the vector's block.
        actions: the action index of each vector.
        meta: free-form facts about how the policy was made (solver, bounds, model).
        blocks: for a model with fully observed variables (a ``.pomdpx``), (X, n) the
            flat states of each joint value x of those variables
            (:func:`stack.planning.pomdpx.observed_blocks`); None: flat vectors.
        obs: with ``blocks``, (K,) the block x of each vector: it is a value only at
            beliefs within that block (SARSOP's ``obsValue``; -inf elsewhere).
    """

    alphas: np.ndarray
    actions: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)
    blocks: np.ndarray | None = None
    obs: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.alphas.ndim != 2 or self.actions.shape != (self.alphas.shape[0],):
            raise ValueError(
                f"alphas {self.alphas.shape} and actions {self.actions.shape} do not match"
            )
        if self.alphas.shape[0] == 0:
            raise ValueError("a policy needs at least one alpha vector")
        if (self.blocks is None) != (self.obs is None):
            raise ValueError("a block policy needs both blocks and obs")
        if self.blocks is not None and self.obs is not None:
            if self.blocks.ndim != 2 or self.blocks.shape[1] != self.alphas.shape[1]:
                raise ValueError(
                    f"blocks {self.blocks.shape} do not fit vectors of {self.alphas.shape[1]}"
                )
            if (
                self.obs.shape != self.actions.shape
                or not ((self.obs >= 0) & (self.obs < len(self.blocks))).all()
            ):
                raise ValueError("obs must give each vector a block")
            X, n = self.blocks.shape
            where = np.full(self.blocks.size, -1)
            where[self.blocks.ravel()] = np.repeat(np.arange(X), n)
            if (where < 0).any():
                raise ValueError("the blocks must cover every state once")
            pos = np.empty(self.blocks.size, dtype=int)
            pos[self.blocks.ravel()] = np.tile(np.arange(n), X)
            object.__setattr__(self, "_where", (where, pos))

    @property
    def n_states(self) -> int:
        return self.alphas.shape[1] if self.blocks is None else self.blocks.size

    def values(self, belief: np.ndarray) -> np.ndarray:
        if self.blocks is not None:
            # a vector of block x is a value at beliefs within block x only
            where, pos = self._where  # type: ignore[attr-defined]
            nz = np.flatnonzero(belief)
            out = np.full(len(self.alphas), -np.inf)
            x = where[nz]
            if nz.size and (x == x[0]).all():
                mine = np.flatnonzero(self.obs == x[0])
                out[mine] = self.alphas[np.ix_(mine, pos[nz])] @ belief[nz]
            return out
        return self.alphas @ belief

    def value(self, belief: np.ndarray) -> float:
        """The lower bound max_k alpha_k . b."""
        return float(self.values(belief).max())

    def action(self, belief: np.ndarray) -> int:
        """The action of the best alpha vector at ``belief``.

        Ties go to the first vector, so the choice is deterministic.
        """
        if belief.shape != (self.n_states,):
            raise ValueError(f"belief has shape {belief.shape}, policy expects ({self.n_states},)")
        return int(self.actions[int(np.argmax(self.values(belief)))])

    def action_values(self, belief: np.ndarray, n_actions: int) -> np.ndarray:
        """Best vector value per action (-inf for actions no vector recommends)."""
        v = self.values(belief)
        out = np.full(n_actions, -np.inf)
        np.maximum.at(out, self.actions, v)
        return out

    # -- files ---------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write the policy at exactly ``path``.

        A ``.policy`` suffix writes SARSOP's XML (:mod:`stack.planning.policy`,
        which SARSOP's ``pomdpsim`` reads); anything else a compressed numpy archive
        (alphas, actions, JSON metadata). The file is written whole and then moved into
        place, so a reader never sees half a policy.
        """
        path = Path(path)
        if path.suffix == ".policy":
            return write_policy_xml(self, path, model=str(self.meta.get("model", "")))
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        layout: dict[str, Any] = {}
        if self.blocks is not None:
            layout = {"blocks": self.blocks, "obs": self.obs}
        with open_write(tmp, "wb") as f:  # a file object: numpy adds no ".npz" to the name
            np.savez_compressed(
                f,
                alphas=self.alphas,
                actions=self.actions,
                meta=np.array(json.dumps(self.meta)),
                **layout,
            )
        tmp.replace(path)
        return path

    @classmethod
    def load(
        cls,
        path: str | Path,
        n_states: int | None = None,
        model_hash: str | None = None,
        obs_blocks: list[np.ndarray] | None = None,
    ) -> AlphaPolicy:
        """Read a policy written by :meth:`save` (numpy archive) or by SARSOP (XML).

        Args:
            path: the file.
            n_states: the model's state count, checked.
            model_hash: the model's :meth:`POMDP.fingerprint`; a policy that records
                the hash of another model is refused (a policy solved for task r1 is
                no policy for r2, though both have 845 states).

        Raises:
            PolicyFileError: unreadable file, missing arrays, a state count that does
                not match ``n_states``, or a policy made for another model.
            obs_blocks: a factored model's layout of SARSOP's vectors
                (:func:`read_policy_xml`; :func:`stack.planning.pomdpx.observed_blocks`).
        """
        path = Path(path)
        if path.is_dir():
            raise PolicyFileError(f"{path} is a directory, not a policy file")
        if is_policy_xml(path):
            return read_policy_xml(path, n_states, obs_blocks)
        try:
            with open_regular(path, MAX_POLICY_BYTES) as f, np.load(f, allow_pickle=False) as data:
                alphas, actions = data["alphas"], data["actions"]
                meta = json.loads(str(data["meta"])) if "meta" in data else {}
                blocks = data["blocks"] if "blocks" in data else None
                obs = data["obs"] if "obs" in data else None
        except FileNotFoundError:
            raise
        except CORRUPT_ARCHIVE_ERRORS as exc:
            raise PolicyFileError(
                f"{path}: not a policy file ({type(exc).__name__}: {exc})"
            ) from None
        if alphas.ndim != 2 or actions.shape != (alphas.shape[0],) or alphas.shape[0] == 0:
            raise PolicyFileError(f"{path}: alphas {alphas.shape} and actions {actions.shape}")
        width = alphas.shape[1] if blocks is None else blocks.size
        if n_states is not None and width != n_states:
            raise PolicyFileError(f"{path}: policy is for {width} states, the model has {n_states}")
        if not np.all(np.isfinite(alphas)):
            raise PolicyFileError(f"{path}: the policy holds non-finite values")
        recorded = meta.get("model_sha256")
        if model_hash is not None and recorded is not None and recorded != model_hash:
            raise PolicyFileError(
                f"{path}: policy was solved for another model (model hash {recorded[:12]}, "
                f"this model's is {model_hash[:12]}); solve this model first"
            )
        try:
            return cls(alphas, actions.astype(int), meta, blocks, obs)
        except ValueError as exc:
            raise PolicyFileError(f"{path}: {exc}") from None


# -- SARSOP's .policy XML -------------------------------------------------------------
#
# <?xml version="1.0" encoding="ISO-8859-1"?>
# <Policy version="0.1" type="value" model="Tiger.pomdp" ...>
# <AlphaVector vectorLength="2" numObsValue="1" numVectors="5">
# <Vector action="1" obsValue="0">-81.5975 28.4025 </Vector> ...
# </AlphaVector> </Policy>
#
# obsValue is the value of the fully observed variable of a factored .pomdpx model (0
# for a .pomdp file). SARSOP's pomdpsim and pomdpeval read what write_policy_xml writes.

MAX_POLICY_BYTES = 1024 * 1024 * 1024


def write_policy_xml(policy: AlphaPolicy, path: str | os.PathLike, model: str = "") -> Path:
    """Write ``policy`` as SARSOP XML at exactly ``path``.

    Values are written with 12 significant digits (SARSOP writes 6), each first lowered
    by its rounding error, so a written vector is never above the one solved: a lower
    bound read back is still a lower bound. Formatting is one ``%`` per vector (about
    0.4 us a value on an idle core, twice as fast as ``repr`` per value).

    Raises:
        ValueError: a vector holds a non-finite value (SARSOP could not read it back).
    """
    if not np.all(np.isfinite(policy.alphas)):
        raise ValueError("the policy holds non-finite values; refusing to write it")
    path = Path(path)
    K, S = policy.alphas.shape
    # a block policy in SARSOP's layout for a .pomdpx model: obsValue x, the vector over
    # block x's states in the order of the other variables' joint value
    n_obs = 1 if policy.blocks is None else len(policy.blocks)
    head = [
        '<?xml version="1.0" encoding="ISO-8859-1"?>',
        f'<Policy version="0.1" type="value" model="{_attr(model)}" '
        'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        'xsi:noNamespaceSchemaLocation="policyx.xsd">',
        f'<AlphaVector vectorLength="{S}" numObsValue="{n_obs}" numVectors="{K}">',
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open_write(tmp, "w", "ascii") as f:
        f.write("\n".join(head) + "\n")
        for line in format_vectors(policy.alphas, policy.actions, obs=policy.obs):
            f.write(line)
        f.write("</AlphaVector> </Policy>\n")
    tmp.replace(path)
    return path


VALUE_FORMAT = "%.12g"  # the written precision; see write_policy_xml
_ROUNDING = 1e-11  # relative: at least the rounding error of VALUE_FORMAT (5e-12)


def format_vectors(
    alphas: np.ndarray, actions: np.ndarray, chunk: int = 64, obs: np.ndarray | None = None
):
    """The ``<Vector>`` lines of SARSOP's XML, a block of vectors at a time (``obs``:
    each vector's obsValue, default 0)."""
    S = alphas.shape[1]
    fmt = '<Vector action="%d" obsValue="%d">' + " ".join([VALUE_FORMAT] * S) + " </Vector>\n"
    obs = np.zeros(len(alphas), dtype=int) if obs is None else obs
    for lo in range(0, len(alphas), chunk):
        block = alphas[lo : lo + chunk]
        # lowered by the rounding error: the written value is at most the solved one
        block = block - np.abs(block) * _ROUNDING - 1e-300
        head = [actions[lo : lo + chunk].astype(float), obs[lo : lo + chunk].astype(float)]
        rows = np.column_stack([*head, block]).tolist()
        yield "".join(fmt % tuple(r) for r in rows)


def seconds_per_value(sample: np.ndarray) -> float:
    """Measured time to format one value of ``sample`` (a block of vectors) as XML."""
    sample = np.atleast_2d(sample)
    t = clock.now()
    for _ in format_vectors(sample, np.zeros(len(sample), dtype=int)):
        pass
    return (clock.now() - t) / max(1, sample.size)


def _attr(text: str) -> str:
    return text.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")


def is_policy_xml(path: str | os.PathLike) -> bool:
    """True when the file starts like an XML document."""
    try:
        with open_regular(path, MAX_POLICY_BYTES) as f:
            head = f.read(64).lstrip()
    except (OSError, ValueError):
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
            the fully observed variables (vector ``obsValue=x`` covers
            ``obs_blocks[x]``): the policy keeps them per block (``AlphaPolicy.blocks``,
            a value only at beliefs within its block); ignored for vectors over all
            the model's states.

    Raises:
        PolicyFileError: not a policy file, or vectors that do not fit the model.
    """
    path = Path(path)
    if path.is_dir():
        raise PolicyFileError(f"{path} is a directory, not a policy file")
    try:
        data = read_bytes_capped(path, MAX_POLICY_BYTES)
    except ValueError as exc:
        raise PolicyFileError(str(exc)) from None
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
            actions.append(int(v.get("action", "")))  # missing: ValueError, reported below
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
    blocks = None
    if obs_blocks is not None and length != sum(len(b) for b in obs_blocks):
        # factored vectors (a flat policy for the same model has vectorLength S): kept
        # per block (RockSample_11_11: 2,048 values a vector, not 249,856)
        for k, x in enumerate(obs):
            if not 0 <= x < len(obs_blocks) or len(obs_blocks[x]) != length:
                raise PolicyFileError(f"{path}: vector {k} does not fit observed value {x}")
        blocks = np.vstack(obs_blocks)
    elif any(x != 0 for x in obs):
        raise PolicyFileError(
            f"{path}: vectors for several observed values (a factored .pomdpx policy); "
            "evaluate it on its .pomdpx model"
        )
    width = alphas.shape[1] if blocks is None else blocks.size
    if n_states is not None and width != n_states:
        raise PolicyFileError(f"{path}: policy is for {width} states, the model has {n_states}")
    meta: dict[str, Any] = {
        "solver": "sarsop-xml",
        "model": root.get("model", ""),
        "file": str(path),
    }
    actions_arr = np.asarray(actions, dtype=int)
    if blocks is None:
        return AlphaPolicy(alphas=alphas, actions=actions_arr, meta=meta)
    return AlphaPolicy(alphas, actions_arr, meta, blocks=blocks, obs=np.asarray(obs, dtype=int))


def relative_gap(lower: float, upper: float) -> float:
    """The gap between two bounds as a fraction of the larger magnitude of the two."""
    return (upper - lower) / max(abs(lower), abs(upper), 1e-12)


@dataclass
class BoundedResult:
    """What every solver's result holds (the policy, its bounds at b0, the time taken,
    the progress reports) and says about its bounds; SearchResult and SolveResult add
    their own figures."""

    policy: AlphaPolicy
    lower_bound: float
    upper_bound: float
    seconds: float
    history: list[Any] = field(default_factory=list)  # pbvi.IterationStats or SearchStats

    @property
    def gap(self) -> float:
        return self.upper_bound - self.lower_bound

    @property
    def relative_gap(self) -> float:
        return relative_gap(self.lower_bound, self.upper_bound)

    @property
    def n_iterations(self) -> int:
        return 0

    def summary(self) -> dict:
        return {
            "lower_bound": self.lower_bound,
            "upper_bound": self.upper_bound,
            "gap": self.gap,
            "relative_gap": self.relative_gap,
            "value_b0": self.lower_bound,
            "alpha_vectors": int(self.policy.alphas.shape[0]),
            "iterations": self.n_iterations,
            "seconds": self.seconds,
        }
