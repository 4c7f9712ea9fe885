"""Our flat policy of a ``.pomdpx`` model in SARSOP's factored layout, for ``pomdpsim``.

``vigil solve-pomdp MODEL.pomdpx`` writes the factored layout itself when it searches
with vectors per observed block (stack/planning/blocksearch.py: fully observed
variables, b0 within one of their values). Other policies of such a model (Perseus's,
the flat search's when b0 spreads over several values) hold vectors over the flat
states (obsValue 0). SARSOP's ``pomdpsim`` reads a .pomdpx model's policy as vectors
per joint value x of the fully observed variables (obsValue x) over the other
variables. This writes every flat vector once per x, restricted to the flat states
with that x
(``stack.planning.pomdpx.observed_blocks``): the same values, so each is still the
value of the same plan from those states.

    python bench/factored_policy.py MODEL.pomdpx FLAT.policy OUT.policy
    pomdpsim MODEL.pomdpx --policy-file OUT.policy --simLen 100 --simNum 1000 --srand 1

RockSample_7_8 (1,627 vectors, 50 robot values): 306 MB, written in ~15 s.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from stack.planning.policy import VALUE_FORMAT, read_policy_xml
from stack.planning.pomdpx import observed_blocks, read_pomdpx


def write_factored(model: Path, flat: Path, out: Path) -> int:
    """Write ``out``; returns the number of vectors written."""
    pomdp = read_pomdpx(model)
    blocks = observed_blocks(pomdp)
    if blocks is None:
        raise ValueError(f"{model} has no fully observed variable: its policy is flat already")
    policy = read_policy_xml(flat, pomdp.n_states)
    K, n = len(policy.alphas), len(blocks[0])
    if any(len(b) != n for b in blocks):
        raise ValueError(f"{model}: blocks of different sizes")
    fmt = " ".join([VALUE_FORMAT] * n)
    with open(out, "w", encoding="ascii") as f:
        f.write('<?xml version="1.0" encoding="ISO-8859-1"?>\n')
        f.write(f'<Policy version="0.1" type="value" model="{model.name}">\n')
        f.write(
            f'<AlphaVector vectorLength="{n}" numObsValue="{len(blocks)}" '
            f'numVectors="{K * len(blocks)}">\n'
        )
        for x, rows in enumerate(blocks):
            sub = policy.alphas[:, rows]  # values already rounded down when first written
            f.writelines(
                f'<Vector action="{int(policy.actions[k])}" obsValue="{x}">'
                + fmt % tuple(sub[k])
                + " </Vector>\n"
                for k in range(K)
            )
        f.write("</AlphaVector> </Policy>\n")
    return K * len(blocks)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model", type=Path)
    ap.add_argument("flat", type=Path, help="a policy vigil solve-pomdp wrote for the model")
    ap.add_argument("out", type=Path)
    args = ap.parse_args(argv)
    try:
        n = write_factored(args.model, args.flat, args.out)
    except (ValueError, OSError) as exc:
        print(f"factored_policy: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: {n} vectors", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
