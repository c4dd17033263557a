#!/bin/sh
# rCFD against fbed's own full runs on the CPU (validation/rcfd/README.md has the results).
# Each validate stage is reused when the command is run again, so a run cut off by a time limit goes on.
# About 8 minutes of wall on the shared 2-core CPU for the runs (database 0-1.5 s, three 1 s continuations),
# then 1-3 minutes per analysis (the half-cell stitches); the diagnosis records three 1.4 s runs (about 2.5 minutes each).
set -e
cd "$(dirname "$0")/../.."
OUT=${OUT:-runs}
V="$OUT/rcfd-validate-bubbling"
# 1. presets/rcfd_bubbling.toml, the grain tracer (jumps on half cells), the paths' default mean sequence
#    (N/10 = 20 frames); the 5 mm-jump variant of the README is Engine(db, jump_grid="cells")
python3 -m app rcfd validate presets/rcfd_bubbling.toml --t0 0.5 --t1 1.5 --t2 2.5 --paths 20 --seed 1 \
    --arch cpu --out "$V" || true
for f in REPORT.md validation.json mixing_validation.png; do cp "$V/$f" "$V/lmean20_$f"; done
cp "$V/rcfd_paths/summary.json" "$V/paths_summary_lmean20.json"
# 2. the same runs, mean sequence 100 frames (0.5 s): a jump's cell averaging every 0.5 s instead of 0.1 s
python3 -c "import sys; from app.rcfd.validate import validate; sys.exit(validate('presets/rcfd_bubbling.toml', \
0.5, 1.5, 2.5, '$V', 20, 1, 3, [], 'cpu', l_mean=100))" || true
for f in REPORT.md validation.json mixing_validation.png; do cp "$V/$f" "$V/lmean100_$f"; done
cp "$V/rcfd_paths/summary.json" "$V/paths_summary_lmean100.json"
# 2b. both with the jumps stitched on the 5 mm cells (bubbling/jumps_on_cells/ in the README)
for L in 20 100; do
    python3 -c "import sys; from app.rcfd.validate import validate; sys.exit(validate('presets/rcfd_bubbling.toml', \
0.5, 1.5, 2.5, '$V', 20, 1, 3, [], 'cpu', l_mean=$L, jump_grid='cells'))" || true
    for f in REPORT.md validation.json mixing_validation.png; do cp "$V/$f" "$V/cells_lmean${L}_$f"; done
done
# 3. where the replay error comes from: frames every fluid step with every grain's position, three gas speeds
for U in 1.8 2.1 2.4; do
    python3 validation/rcfd/diagnose_replay.py record presets/rcfd_bubbling.toml "$OUT/diag_U$U" --from 0.4 \
        --to 1.4 --set "boundary.bottom.velocity=[0.0, 0.0, $U]"
    python3 validation/rcfd/diagnose_replay.py analyze "$OUT/diag_U$U" --tag 'z<0.015' \
        > validation/rcfd/diagnosis/replay_U$U.json
done
