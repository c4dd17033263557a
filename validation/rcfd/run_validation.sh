#!/bin/sh
# rCFD against fbed's own full runs on the CPU (validation/rcfd/README.md has the results).
# Each validate stage is reused when the command is run again, so a run cut off by a time limit goes on.
# About 8 minutes of wall on the shared 2-core CPU for the runs (database 0-1.5 s, three 1 s continuations),
# then about a minute per analysis with matched jumps (1-3 minutes with half-cell stitches). H3=1 adds 3 s
# continuations of the same database (about 15 minutes more); LONG=1 the 2 s database (0.5-2.5 s, continuations
# to 3.5 s, then to 5.5 s: about 30 minutes more); DIAG=1 the diagnosis, which records three 1.4 s runs (about
# 2.5 minutes each). Wall times on a loaded machine vary by 2-3x.
set -e
cd "$(dirname "$0")/../.."
OUT=${OUT:-runs}
V="$OUT/rcfd-validate-bubbling"
val() {  # val DIR L_MEAN JUMP NAME [SENS]: one validate on DIR's runs (T0, T1, T2), its report copied to DIR/NAME_*;
        # SENS=True adds the sensitivity check (frames doubled, sequences halved)
    python3 -c "import sys; from app.rcfd.validate import validate; sys.exit(validate('presets/rcfd_bubbling.toml', \
$T0, $T1, $T2, '$1', 20, 1, 3, [], 'cpu', l_mean=$2, jump='$3', sensitivity=${5:-False}))" || true
    for f in REPORT.md validation.json mixing_validation.png; do cp "$1/$f" "$1/$4_$f"; done
    cp "$1/rcfd_paths/summary.json" "$1/$4_paths_summary.json"
}
extend() {  # extend FROM TO T: copies of FROM's A and C1-C3 in TO, the continuations resumed to T [s]
    mkdir -p "$2"
    for d in A C1 C2 C3; do [ -d "$2/$d" ] || cp -r "$1/$d" "$2/$d"; done
    for k in 1 2 3; do
        python3 -c "import sys, pathlib; from app.run import run; from app.rcfd.validate import _finished; \
d = pathlib.Path('$2/C$k'); sys.exit(0 if _finished(d, $3) else run(None, ['run.duration=$3'], resume=str(d), arch='cpu'))"
    done
}
# 1. presets/rcfd_bubbling.toml, the grain tracer, jumps matched grain to grain on half cells (the default) and
#    stitched on half cells (before), mean sequence N/10 = 20 frames (0.1 s) and 100 frames (0.5 s)
T0=0.5 T1=1.5 T2=2.5
for J in match stitch; do
    for L in 20 100; do val "$V" $L $J "${J}_lmean$L"; done
done
# 1a. the design note's sensitivity check on the matched jumps (validation/rcfd/README.md, section 00)
val "$V" 100 match sensitivity_lmean100 True
# 1b. the same database with 3 s continuations (t50 and t90 of Lacey's index need more than 1 s)
if [ "${H3:-0}" = 1 ]; then
    extend "$V" "$V-3s" 4.5
    T0=0.5 T1=1.5 T2=4.5
    for J in match stitch; do val "$V-3s" 100 $J "${J}_lmean100"; done
    val "$V-3s" 20 match match_lmean20
fi
# 2. a database twice as long (0.5-2.5 s), 1 s and then 3 s continuations
if [ "${LONG:-0}" = 1 ]; then
    T0=0.5 T1=2.5 T2=3.5
    for L in 40 100 200; do val "$V-long" $L match "match_lmean$L"; done
    extend "$V-long" "$V-long-3s" 5.5
    T2=5.5
    for L in 200 100; do val "$V-long-3s" $L match "match_lmean$L"; done
fi
# 3. where the replay error comes from: frames every fluid step with every grain's position, three gas speeds
if [ "${DIAG:-0}" = 1 ]; then
    for U in 1.8 2.1 2.4; do
        python3 validation/rcfd/diagnose_replay.py record presets/rcfd_bubbling.toml "$OUT/diag_U$U" --from 0.4 \
            --to 1.4 --set "boundary.bottom.velocity=[0.0, 0.0, $U]"
        python3 validation/rcfd/diagnose_replay.py analyze "$OUT/diag_U$U" --tag 'z<0.015' \
            > validation/rcfd/diagnosis/replay_U$U.json
    done
fi
