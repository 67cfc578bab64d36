#!/usr/bin/env bash
# The exact commands that made the pointing-cones warm-start model
# (solvers/warmstart/models/pointing-cones.npz, 8 heads, since session 39; steps 1-4 made the
# single-head network shipped before it and the table of its data). Problems are deterministic
# in (family, seed, index); a stopped run continues with the same command. Which problems get exact answers
# depends on the solver's code and on machine load (time budgets). Seed 31 was solved first, when
# 62 % came out exact; seeds 32 and 33 after later solver fixes, 81 % (docs/DATASET.md; records
# name their solver_commit). A rerun of step 1 today gives about 81 % on seed 31 too: more exact
# training solutions and a different model, not the shipped one.
# On 2 cores: about 55 min (1), 50 min (2), 1 min (3), 5 min (4), 50 min (5), 5 min (6), 2 min (7),
# 45 min and 7 min (8), 2 min (9).
set -euo pipefail
mkdir -p runs/data runs

# 1. the data: 6,000 problems, robust route (collocation, then the exact refinements: cones
#    inactive, touch-point junctions)
slew generate --family pointing-cones --n 6000 --seed 31 -o runs/data/pointing-cones-touch-s31.jsonl --workers 2

# 2. 5,000 more (generated after the switch-time touch formulation and the short-pulse fix of
#    the event-driven flow, which make about 85 % of the answers exact instead of 62 %)
slew generate --family pointing-cones --n 3000 --seed 32 -o runs/data/pointing-cones-touch-s32.jsonl --workers 2
slew generate --family pointing-cones --n 2000 --seed 33 -o runs/data/pointing-cones-touch-s33.jsonl --workers 2

# 3. the network (exact answers only), exported for numpy inference, and next to it the table of
#    the same exact solutions (pointing-cones.nn.npz, float32) whose nearest neighbours the
#    shipped warm start tries before the network's guess (solvers/warmstart/cone_ensemble.py).
#    Until session 39 this network (one head; the config then had no 'heads') and its table
#    (7,674 exact solutions) were the shipped files; step 6 starts from that table.
slew train --config training/warmstart/configs/pointing-cones.yaml \
    --data runs/data/pointing-cones-touch-s31.jsonl runs/data/pointing-cones-touch-s32.jsonl \
           runs/data/pointing-cones-touch-s33.jsonl \
    --out runs/ws-cones-final --seed 0 --export runs/ws-cones-s31-33/pointing-cones.npz

# 4. the evaluation of those files in docs/WARMSTART.md (held-out problems of a fresh seed; the
#    57.7-62.2 % rows): it ran with them installed as the shipped ones; since session 39
#    --model pointing-cones is the 8-head model of step 6 (step 7 evaluates that).
#    --model solvers/warmstart/models/pointing-cones.npz evaluates the network alone
slew evaluate --family pointing-cones --model pointing-cones \
    --n 1000 --seed 20261122 --baseline-n 50 --out runs/evaluate-cones \
    --train-data runs/data/pointing-cones-touch-s31.jsonl runs/data/pointing-cones-touch-s32.jsonl \
    runs/data/pointing-cones-touch-s33.jsonl

# 5. (session 39) 10,000 more problems with the code of that day (solve_default: auto, whose cone
#    challenger used a first 8-head network, trained on the table alone and installed as the
#    shipped network while these ran: step 5a): 4,084 and 4,161 exact
git show 77a1372:solvers/warmstart/models/pointing-cones.nn.npz > runs/data/pointing-cones-s31-33.nn.npz
# 5a. (that day's command read the same table in place, solvers/warmstart/models/pointing-cones.nn.npz
#     at 77a1372; only the network was installed, beside that table)
slew train --config training/warmstart/configs/pointing-cones.yaml --data runs/data/pointing-cones-s31-33.nn.npz \
    --out runs/ws-cones-heads-table --seed 0 --export runs/ws-cones-heads-table/export/pointing-cones.npz
cp runs/ws-cones-heads-table/export/pointing-cones.npz solvers/warmstart/models/pointing-cones.npz
slew generate --family pointing-cones --n 5000 --seed 34 -o runs/data/pointing-cones-s34.jsonl --workers 2
slew generate --family pointing-cones --n 5000 --seed 35 -o runs/data/pointing-cones-s35.jsonl --workers 2

# 6. the shipped network: 8 heads (training/warmstart/configs/pointing-cones.yaml), trained on
#    the table as shipped before (the exact solutions of steps 1-2, sha256 6acbec74...; a rerun of
#    step 3 gives other data, see the top) and the exact solutions of step 5; --export writes
#    the network and the table of all these solutions (solvers/warmstart/cone_ensemble.py), whose
#    card names the data files
slew train --config training/warmstart/configs/pointing-cones.yaml \
    --data runs/data/pointing-cones-s31-33.nn.npz runs/data/pointing-cones-s34.jsonl \
           runs/data/pointing-cones-s35.jsonl \
    --out runs/ws-cones-heads --seed 0 --export solvers/warmstart/models/pointing-cones.npz

# 7. its evaluation (docs/WARMSTART.md): the shipped warm start (table, then the network's heads)
#    against the nearest-neighbour lookup of the same solutions
slew evaluate --family pointing-cones --model pointing-cones \
    --n 1000 --seed 20261122 --baseline-n 50 --out runs/evaluate-cones-heads \
    --train-data solvers/warmstart/models/pointing-cones.nn.npz

# 8. (session 40) 10,000 more problems (seeds 36 and 37; the code of that day, with the session-39
#    model shipped), then the shipped network retrained, as in step 6, on the table shipped in
#    session 39 (whose card names its data files) and the exact solutions of seeds 36 and 37
git show fede8b8:solvers/warmstart/models/pointing-cones.nn.npz > runs/data/pointing-cones-s31-35.nn.npz
slew generate --family pointing-cones --n 5000 --seed 36 -o runs/data/pointing-cones-s36.jsonl --workers 2
slew generate --family pointing-cones --n 5000 --seed 37 -o runs/data/pointing-cones-s37.jsonl --workers 2
slew train --config training/warmstart/configs/pointing-cones.yaml \
    --data runs/data/pointing-cones-s31-35.nn.npz runs/data/pointing-cones-s36.jsonl \
           runs/data/pointing-cones-s37.jsonl \
    --out runs/ws-cones-s40 --seed 0 --export solvers/warmstart/models/pointing-cones.npz

# 9. its evaluation (docs/WARMSTART.md; the learned+table row: the sequences of the nearest tabled
#    solutions where the candidates fail, solvers/cone_routes.py)
slew evaluate --family pointing-cones --model pointing-cones \
    --n 1000 --seed 20261122 --baseline-n 50 --out runs/evaluate-cones-s40 \
    --train-data solvers/warmstart/models/pointing-cones.nn.npz
