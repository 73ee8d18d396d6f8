#!/usr/bin/env bash
# Accuracy IV, 2026-11-28 (docs/research/campaigns.md): the uniform soup of the third cycle's end annealed at 256x448 with seeds
# 30 and 31 (runs/anneal-cycle3-crop256, runs/anneal-cycle3-crop256-seed31: the same init, other batches). The two
# anneals' Middlebury means differ by 2 % (3.030 / 19.05 against 3.098 / 19.43), as much as any candidate differs
# from cade-v13; averaging the seeds' weights takes the draw out of the candidate. Checked against cade-v13 by:
#   REFINEMENT=rank-sgbm-two-scales CHOOSER_CANDIDATES=rank-sgbm \
#     benchmarks/candidate_check.sh runs/soup-c3a256-seeds/last.pt c3soup OUT cade-v13
# Not in the tree (a weights-only checkpoint): the two anneals' commands, then this one, make it again.
exec .venv/bin/python -m cade_cli.train soup runs/anneal-cycle3-crop256/last.pt runs/anneal-cycle3-crop256-seed31/last.pt \
  --out runs/soup-c3a256-seeds/last.pt "$@"
