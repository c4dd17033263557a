#!/bin/sh
# rCFD against fbed's own full runs on the CPU (validation/rcfd/README.md has the results).
# Each stage is reused when the command is run again, so a run cut off by a time limit goes on.
# rcfd_small: about 9 minutes of wall on the shared 2-core CPU for the runs (database 0-1.5 s, three 1 s
# continuations); verma_small: about 17 minutes; then seconds per analysis. The --lag variants reuse the same runs.
set -e
cd "$(dirname "$0")/../.."
OUT=${OUT:-runs}
# 1. the design note's lateral tag (x < 0)
python3 -m app rcfd validate presets/rcfd_small.toml --t0 0.5 --t1 1.5 --t2 2.5 --paths 20 --seed 1 \
    --arch cpu --out "$OUT/rcfd-validate" || true
# 2. a vertical tag (about the lower half of the bed) at lags 1, 10, 20 and 53 (one slug period)
for LAG in 1 10 20 53; do
    python3 -m app rcfd validate presets/rcfd_small.toml --t0 0.5 --t1 1.5 --t2 2.5 --paths 20 --seed 1 \
        --arch cpu --out "$OUT/rcfd-validate-z" --set 'probes.rcfd_tag="z<0.018"' --lag $LAG || true
    cp "$OUT/rcfd-validate-z/REPORT.md" "$OUT/rcfd-validate-z/REPORT_lag$LAG.md"
    cp "$OUT/rcfd-validate-z/validation.json" "$OUT/rcfd-validate-z/validation_lag$LAG.json"
    cp "$OUT/rcfd-validate-z/mixing_validation.png" "$OUT/rcfd-validate-z/mixing_validation_lag$LAG.png"
done
# 3. verma_small (14,000 grains, 50 mm): database 0.5-1.0 s, continuations to 1.5 s, a vertical tag on a cell face
V="--t0 0.5 --t1 1.0 --t2 1.5 --paths 20 --seed 1 --arch cpu --out $OUT/rcfd-validate-verma"
for LAG in 1 10 20; do
    python3 -m app rcfd validate presets/verma_small.toml $V --lag $LAG --set 'probes.rcfd_tag="z<0.025"' \
        --set probes.rcfd_z_max=0.1 --set 'probes.analysis="none"' --set 'probes.planes=[]' \
        --set probes.planes_interval=0 --set probes.volume_interval=0 || true
    cp "$OUT/rcfd-validate-verma/REPORT.md" "$OUT/rcfd-validate-verma/REPORT_lag$LAG.md"
done
