"""The network alone (a training checkpoint, no SGBM refinement, no chooser) on the real check,
scored as training validates it: pooled EPE and bad-3 over msir-outdoor's pseudo ground truth
(cade_cli.train.validation.real_cross_spectral_set, evaluate). Needs the train extra (torch).

    .venv/bin/python benchmarks/raw_real_check.py --data-dir ../shared/data runs/fast192-2d/last.pt [MORE.pt ...]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+", type=Path, help="fit checkpoints (last.pt)")
    parser.add_argument("--data-dir", type=Path, required=True, help="the folder holding msir-outdoor")
    args = parser.parse_args(argv)
    from cade_cli.matching.network import RANGE_MARGIN
    from cade_cli.train.export import load_checkpoint
    from cade_cli.train.pairs import network_input_of
    from cade_cli.train.validation import evaluate, real_cross_spectral_set

    for checkpoint in args.checkpoints:
        net, state = load_checkpoint(checkpoint)
        config = state.get("config", {})
        kind = network_input_of(config.get("training_mode", "cade"), config.get("network_input"))
        pairs = real_cross_spectral_set(args.data_dir, kind, net.levels - RANGE_MARGIN)
        if not pairs:
            parser.error(f"{args.data_dir} holds no msir-outdoor")
        start = time.perf_counter()
        epe, bad3 = evaluate(net, pairs, "cpu")
        print(f"{checkpoint}: step {state['step']}, msir-outdoor EPE {epe:.3f} bad3 {bad3:.2f} "
              f"({time.perf_counter() - start:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
