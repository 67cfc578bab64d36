#!/usr/bin/env bash
# The exact commands that made the shipped warm-start model
# (solvers/warmstart/models/full-attitude.npz). The problems of a dataset are deterministic in
# (family, seed, index); a run that is stopped can be continued with the same command. Which
# problems a route solves within its wall-clock time budget can depend on machine load, so a
# rerun gives nearly, not exactly, the same records (and a correspondingly different model;
# training itself is bit-reproducible for fixed data and seed).
# On 2 cores: about 10 min (1), 16 min (3), 3 min (4), 35 min (5), 5 min (6), 12 min (7).
set -euo pipefail
mkdir -p runs/solutions runs/data runs

# 1. unbiased data from the robust route (collocation, exact refinement, classical multi-start)
slew generate --family full-attitude --n 1000 --seed 1   -o runs/solutions/full-attitude-seed1.jsonl
slew generate --family full-attitude --n 200  --seed 100 -o runs/solutions/full-attitude-seed100.jsonl

# 2. the bootstrap model that seeds the bulk data. It is shipped
#    (training/warmstart/bootstrap/bootstrap1.npz, sha256 426cfb96…) because its own data came
#    from two runs that were stopped early (a robust-route run, seed 11, 1,659 records, and a
#    warm-route run from a smaller bootstrap model, seed 12, 5,521 records); see docs/WARMSTART.md.

# 3. bulk data: the bootstrap model's guess alone, indirect solver, 0.3 s budget, no fallback
#    (a problem it does not solve is a failure record)
slew generate --family full-attitude --n 25000 --seed 13 -o runs/data/full-attitude-warm-s13.jsonl \
    --solve-fn training.generate:solve_warm \
    --solve-options '{"model": "training/warmstart/bootstrap/bootstrap1.npz", "time_budget": 0.3}'

# 4. the first network (the model shipped until 2026-11-22 evening, sha256 006bbf0d…), which
#    seeds the table data of step 5
slew train --data runs/solutions/full-attitude-seed1.jsonl runs/solutions/full-attitude-seed100.jsonl \
    runs/data/full-attitude-warm-s13.jsonl --out runs/ws-final --seed 0

# 5. solve()'s answers on 20,000 new problems (the first network's guess, then auto's collocation
#    route; the singular table itself off, so that its singular answers come from collocation's
#    sequences), then the singular table (solvers/warmstart/models/full-attitude-singular.npz):
#    which problems are singular and their switching sequences. tf_tol 5e-4 of tf: about 3x the
#    largest gap to the collocation route's answer measured on held-out problems (docs/WARMSTART.md).
#    (seed 14 was generated before the option existed, with '{"fallback": true}': the same route)
for s in 14 15; do
  slew generate --family full-attitude --n 10000 --seed $s -o runs/data/full-attitude-s$s.jsonl \
      --solve-fn training.generate:solve_warm \
      --solve-options '{"model": "runs/ws-final/model.npz", "fallback": true, "singular_table": false}'
done
python -m training.warmstart.singular_table \
    --data runs/data/full-attitude-s14.jsonl runs/data/full-attitude-s15.jsonl \
    --out solvers/warmstart/models/full-attitude-singular.npz --tf-rel-tol 5e-4

# 6. the shipped network, on all 39,494 exact solutions, exported for numpy inference, and next to
#    it the table of the same solutions (full-attitude.nn.npz, float32), whose nearest neighbours
#    the shipped warm start tries after the network's guess (solvers/warmstart/attitude_ensemble.py)
DATA="runs/solutions/full-attitude-seed1.jsonl runs/solutions/full-attitude-seed100.jsonl
      runs/data/full-attitude-warm-s13.jsonl runs/data/full-attitude-s14.jsonl runs/data/full-attitude-s15.jsonl"
slew train --data $DATA --out runs/ws-big --seed 0 --export solvers/warmstart/models/full-attitude.npz

# 7. the evaluation in README / docs/WARMSTART.md: the shipped warm start (network, then table),
#    then the network alone (--model solvers/warmstart/models/full-attitude.npz)
slew evaluate --model default --n 1000 --seed 20261122 --baseline-n 100 --out runs/evaluate --train-data $DATA
slew evaluate --model solvers/warmstart/models/full-attitude.npz --n 1000 --seed 20261122 --baseline-n 0 \
    --out runs/evaluate-network --train-data $DATA
