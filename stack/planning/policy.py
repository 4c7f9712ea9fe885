"""An alpha-vector policy: V(b) = max_k alpha_k . b, action of the maximising vector."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


class PolicyFileError(ValueError):
    """A policy file that cannot be read or does not fit the model."""


@dataclass(frozen=True, eq=False)
class AlphaPolicy:
    """Alpha vectors (K, S) with their actions (K,).

    Attributes:
        alphas: one row per vector.
        actions: the action index of each vector.
        meta: free-form facts about how the policy was made (solver, bounds, model).
    """

    alphas: np.ndarray
    actions: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.alphas.ndim != 2 or self.actions.shape != (self.alphas.shape[0],):
            raise ValueError(
                f"alphas {self.alphas.shape} and actions {self.actions.shape} do not match"
            )
        if self.alphas.shape[0] == 0:
            raise ValueError("a policy needs at least one alpha vector")

    @property
    def n_states(self) -> int:
        return self.alphas.shape[1]

    def values(self, belief: np.ndarray) -> np.ndarray:
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

        A ``.policy`` suffix writes SARSOP's XML (:mod:`stack.planning.sarsop_policy`,
        which SARSOP's ``pomdpsim`` reads); anything else a compressed numpy archive
        (alphas, actions, JSON metadata). The file is written whole and then moved into
        place, so a reader never sees half a policy.
        """
        path = Path(path)
        if path.suffix == ".policy":
            from stack.planning.sarsop_policy import write_policy_xml

            return write_policy_xml(self, path, model=str(self.meta.get("model", "")))
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as f:  # a file object: numpy adds no ".npz" to the name
            np.savez_compressed(
                f, alphas=self.alphas, actions=self.actions, meta=np.array(json.dumps(self.meta))
            )
        tmp.replace(path)
        return path

    @classmethod
    def load(
        cls, path: str | Path, n_states: int | None = None, model_hash: str | None = None
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
        """
        path = Path(path)
        if path.is_dir():
            raise PolicyFileError(f"{path} is a directory, not a policy file")
        from stack.planning.sarsop_policy import is_policy_xml, read_policy_xml

        if is_policy_xml(path):
            return read_policy_xml(path, n_states)
        try:
            with np.load(path, allow_pickle=False) as data:
                alphas, actions = data["alphas"], data["actions"]
                meta = json.loads(str(data["meta"])) if "meta" in data else {}
        except FileNotFoundError:
            raise
        except (OSError, KeyError, ValueError, EOFError) as exc:
            raise PolicyFileError(f"{path}: not a policy file ({exc})") from None
        if alphas.ndim != 2 or actions.shape != (alphas.shape[0],) or alphas.shape[0] == 0:
            raise PolicyFileError(f"{path}: alphas {alphas.shape} and actions {actions.shape}")
        if n_states is not None and alphas.shape[1] != n_states:
            raise PolicyFileError(
                f"{path}: policy is for {alphas.shape[1]} states, the model has {n_states}"
            )
        if not np.all(np.isfinite(alphas)):
            raise PolicyFileError(f"{path}: the policy holds non-finite values")
        recorded = meta.get("model_sha256")
        if model_hash is not None and recorded is not None and recorded != model_hash:
            raise PolicyFileError(
                f"{path}: policy was solved for another model (model hash {recorded[:12]}, "
                f"this model's is {model_hash[:12]}); solve this model first"
            )
        return cls(alphas=alphas, actions=actions.astype(int), meta=meta)
