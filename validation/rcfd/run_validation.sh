#!/bin/sh
# rCFD against fbed's own full runs on the CPU (validation/rcfd/README.md has the results).
# Each validate stage is reused when the command is run again, so a run cut off by a time limit goes on.
# About 8 minutes of wall on the shared 2-core CPU for the runs (database 0-1.5 s, three 1 s continuations),
# then a minute or two per analysis; the diagnosis records three 1.4 s runs (about 2.5 minutes each).
set -e
cd "$(dirname "$0")/../.."
OUT=${OUT:-runs}
V="$OUT/rcfd-validate-bubbling"
# 1. presets/rcfd_bubbling.toml, the grain tracer, the paths' default mean sequence (N/10 = 20 frames)
python3 -m app rcfd validate presets/rcfd_bubbling.toml --t0 0.5 --t1 1.5 --t2 2.5 --paths 20 --seed 1 \
    --arch cpu --out "$V" || true
for f in REPORT.md validation.json mixing_validation.png; do cp "$V/$f" "$V/lmean20_$f"; done
# 2. the same runs, mean sequence 100 frames (0.5 s): a jump's cell averaging half as often as every 0.1 s
python3 -c "import sys; from app.rcfd.validate import validate; sys.exit(validate('presets/rcfd_bubbling.toml', \
0.5, 1.5, 2.5, '$V', 20, 1, 3, [], 'cpu', l_mean=100))" || true
for f in REPORT.md validation.json mixing_validation.png; do cp "$V/$f" "$V/lmean100_$f"; done
# 3. where the replay error comes from: frames every fluid step with every grain's position, three gas speeds
for U in 1.8 2.1 2.4; do
    python3 validation/rcfd/diagnose_replay.py record presets/rcfd_bubbling.toml "$OUT/diag_U$U" --from 0.4 \
        --to 1.4 --set "boundary.bottom.velocity=[0.0, 0.0, $U]"
    python3 validation/rcfd/diagnose_replay.py analyze "$OUT/diag_U$U" --tag 'z<0.015' \
        > validation/rcfd/diagnosis/replay_U$U.json
done
