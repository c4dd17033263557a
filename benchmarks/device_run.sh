#!/usr/bin/env bash
# One call on the lent GPU machine (see ../shared/device/README.md): benchmarks and runs too large
# for the CPU, packed into $OUT/results.tgz. Usage on the device, from the project root:
#   source .devkit/setup.sh && FBED_COMMIT=<hash> bash benchmarks/device_run.sh STAGE...
# Stages: bench (DEM throughput, render cost), dem (the DEM substep alone: a 1M-grain tri-disperse bed with
# elastic-plastic rolling friction and a 1M monodisperse one, float32, the latter also with its ids shuffled,
# sorted by cell and not (dem_substep.py --shuffle [--sort-interval 0]), then the Verma bed for 0.05 s from its
# fill: particle-substeps/s and bytes_per_grain in runs/verma_dem/summary.json), small (boyce_small with video), boyce (full rig),
# sweep (the injection-time sweep from the cached bed), verma_start (the full Verma run, started in its
# own process session so that it outlives this call: the machine stays lent while later calls poll it),
# wait (poll the background run until it ends or LIMIT_wait), verma_pack (its last state packed with the grains'
# speeds into $OUT/verma_state.h5, for the next session to go on from: see VERMA_FROM below), accuracy / stiffness (the full-size benches),
# gas (the gas step alone on the Verma grid 32x32x116 and on 32x32x64 with a bed's void fraction and drag:
# ms per step, then launches and host reads per step, then the launches' host cost: Taichi's own call against
# the cached plans of app/sim/launch.py, interleaved; issue 18's target is <= 3 ms per Verma step on one H200),
# grid_ab (the gas step and the DEM substep with Taichi's CUDA launch width saturating_grid_dim at its default,
# 2112 and 1056 blocks: A/B in one call), gas_profile (the same scene under Taichi's kernel profiler: each kernel's tasks and device time per step, sorted),
# coarse (the pressure V-cycle's coarse levels in one launch, one block on CUDA, checked against a launch per
# level: run it first), dem_scan (the DEM build's cell-list scan as one block on CUDA, checked against the one-thread
# scan, with the cost of a build and the substep's tasks by device time: run it first too), coarse_ab (the gas step timed without that cycle), coarse_cells (the
# gas step with the cycle from 0, 4096 and 16384 cells down), series (issue 21: verma_small on the GPU, its summary.json wall_split with the callbacks' share, then the host
# reads per fluid step of its first 0.1 s, the step's and the callbacks', by benchmarks/series_reads.py), mri_frame and
# rcfd_frame (a 1e6-grain frame of the synthetic MRI and of the rCFD probe's grain cells: host against device).
# Before any call: `python3 benchmarks/device_carry.py --carry .devkit [more carried paths]` says whether what the
# call takes (the tree with validation/ moved aside, and the carried paths) fits its 64 MiB (exit 1 if not).
# Before a call that runs the cavity or the Verma analysis: `mkdir -p runs && cp -r ../shared/reference runs/`
# here, and carry [".devkit", "runs/reference"] (../shared is not copied to the device).
# MRI poppy-seed bed (issue 19; validation/mri/README.md): mri_prepare (fill and settle the 1e6 grains, then pack
# the bed with `fbed pack --resolution 5e-7` into $OUT/mri_bed.h5, ~4.4 MB, for later sessions to carry as
# runs/mri_bed.h5: carry [".devkit", "runs/mri_bed.h5"], validation/ moved aside, ~62 of the 64 MiB), mri_law (one drag law,
# MRI_LAW=koch_hill|di_felice|gidaspow|beetstra, from runs/mri_bed.h5 when present; MRI_SET adds --set overrides,
# e.g. "--set run.duration=0.6" for a cost measurement), mri_sweep_start (the four laws in the background, like
# verma_start; poll with mri_wait), mri_compare (fbed analyze of the sweep: the laws side by side), mri_umf (the
# U_mf curves of the four laws in the 24 mm column), mri_rcfd (issue 20: `fbed rcfd analyze` and a 10 s `rcfd run`
# of RCFD_PATHS paths, default 5, on runs/mri_$MRI_LAW, which must have recorded rCFD frames: give mri_law e.g.
# MRI_SET="--set probes.rcfd_from=1.6 --set probes.rcfd_z_max=0.25 --set probes.rcfd_tag=z<0.065"; a million
# grains are routed along a flow on the 3 mm cells (the default above 10,000 grains: 2.2 s a jump on one core,
# the jumps built and the paths moved in parallel on the host's cores, the jumps stored as they finish in
# $R/rcfd/matchings.h5, so mri_rcfd run again on the warm machine after a cut-off goes on from them; the whole
# stage about 2 minutes on 16 cores, estimated from a synthetic database on one, benchmarks/rcfd_scale.py); a stitch, --jump stitch, over-mixes the grain tracer:
# validation/rcfd/README.md, 00b and 0000a, before reading its mixing). Estimated (not measured) on one H200: 240-400 s per simulated
# second of the 1e6-grain bed, so mri_prepare 2-4 min and a 0.3 s mri_law cost probe 2-3 min fit one command
# together; a full law (3.1 s) is 13-21 min and fits no 10-minute command: cut it with MRI_SET (run.duration,
# output.average_from) to (LIMIT - 60 s) / measured cost; validation/mri/README.md has the table. A law's run
# ends packed with its grains' speeds in $OUT/mri_state_<law>.h5 (`fbed pack --speed-resolution 1e-2`); a later
# session that carries it as runs/mri_state_<law>.h5 goes on with that law from its fluidized end (the inlet at
# full speed from 0, analysed from 0.02 s): carry [".devkit", "runs/mri_state_<law>.h5"] with validation/,
# benchmarks/accuracy, benchmarks/stiffness and docs/ moved aside (8.0 MB left for it; `benchmarks/device_carry.py
# --aside validation benchmarks/accuracy benchmarks/stiffness docs --carry .devkit runs/mri_state_<law>.h5`).
# Back here, one law's sessions are analysed together: `fbed analyze RUN_1 RUN_2 ... --out runs/<law>-pooled`.
# Keep LIMIT_<stage> at least 40 s under the call's timeout: the packing below needs the time.
# The accuracy and stiffness stages resume (--resume): to go on from rows already committed, copy them first,
# e.g. `mkdir -p runs/accuracy_full && cp benchmarks/accuracy/full_gpu/accuracy.csv runs/accuracy_full/`, and
# carry runs/accuracy_full on that first call only (a carried path replaces the device's copy: later calls would
# lose the rows measured since); a stage cut off by its limit goes on when the same stage is called again.
set -uo pipefail
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"  # the scripts import app as installed: here, this checkout's
L=runs/devout; mkdir -p $L  # inside runs/ (git-ignored): the device keeps it between calls
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv > "$L/gpu.txt" 2>&1
[ -d runs/reference ] && export FBED_REFERENCE=$PWD/runs/reference  # X-ray, Ghia: for the analyses' reference columns
# BUDGET=<s>: the whole call's seconds (the run tool's timeout_s less its start, e.g. 540 of 600). Each stage's limit
# is then cut to what is left of it less 45 s for the packing below, and a stage with under 30 s left is skipped, so a
# call whose stages all run to their limits still packs its results instead of being killed first. After each stage
# its exit and the tail of its log go into $OUT/progress.txt (one file): that much comes back even from a call killed
# by the run tool's timeout.
# A check stage that failed in an earlier call on this warm machine turned its path off for the later calls too
# (the app also checks both barrier paths at start-up on CUDA: app/sim/dem/scan.py, app/sim/gas/cycle_check.py)
[ -f "$L/fallbacks.env" ] && { source "$L/fallbacks.env"; cat "$L/fallbacks.env"; }
# pack_moving RUN_DIR OUT_FILE [FLAGS]: the run's last state (bed.h5, or the checkpoint of a run its limit cut)
# packed with the grains' speeds (FLAGS: default --resolution 2e-6 --speed-resolution 1e-2) and copied to $OUT
pack_moving() {
  local src=$1/bed.h5 out=$2; shift 2
  [ -f "$src" ] || src=${src%/bed.h5}/checkpoint.h5
  [ $# -gt 0 ] || set -- --resolution 2e-6 --speed-resolution 1e-2
  [ -f "$src" ] && python3 -m app pack "$src" "$out" "$@" && cp "$out" "$OUT/"
}
# keep_records RUN_DIR NAME GROUP... [--quantize]: the run's analysis records (those run.h5 groups), its config.toml
# and summary.json in $OUT/NAME (benchmarks/run_records.py, under 16 MiB), so that a case's sessions can be pooled
# back here: `python3 benchmarks/pool_sessions.py S1/NAME S2/NAME ... --out runs/DIR` unpacks, pools and compares
keep_records() {
  local run=$1 name=$2
  shift 2
  [ -n "${OUT:-}" ] && [ -f "$run/run.h5" ] && python3 benchmarks/run_records.py pack "$run" "$OUT/$name" --groups "$@"
  return 0
}
# A Verma run that outlasts a session goes on in the next: `verma_pack` packs its last state with the grains' speeds
# into $OUT/verma_state.h5; carried back as runs/verma_state.h5 (present when this call starts), `verma` and
# `verma_start` go on from it, fluidized: the inlet at full speed from 0, 3 s analysed from 0.02 s (VERMA_SET can
# set run.duration to what the first session left of the preset's 1.0-6.5 s window); back here, the sessions'
# tables are one: `fbed analyze runs/verma runs/verma-2 ... --out runs/verma-pooled`
VERMA_FROM=()
[ -f runs/verma_state.h5 ] && VERMA_FROM=(--set particles.count=0 \
  --set "particles.initial_state=\"$PWD/runs/verma_state.h5\"" --set 'boundary.bottom.schedule=[[0.0,1.0]]' \
  --set run.duration=3.0 --set output.average_from=0.02)
VERMA_FROM_Q=""  # the same, quoted for verma_start's bash -c
[ ${#VERMA_FROM[@]} -gt 0 ] && VERMA_FROM_Q=$(printf '%q ' "${VERMA_FROM[@]}")
BUDGET=${BUDGET:-0}
call_start=$(date +%s)
for stage in "$@"; do
  start=$(date +%s)
  lim=$(eval echo "\${LIMIT_$stage:-590}")  # e.g. LIMIT_boyce=300: SIGTERM stops the run cleanly in time
  if [ "$BUDGET" -gt 0 ]; then
    left=$(( BUDGET - (start - call_start) - 45 ))
    if [ "$left" -lt 30 ]; then
      echo "$stage: skipped, ${left} s of BUDGET=$BUDGET left" | tee -a "$L/stages.txt"
      [ -n "${OUT:-}" ] && echo "== $stage: skipped (budget)" >> "$OUT/progress.txt"
      continue
    fi
    [ "$lim" -gt "$left" ] && lim=$left
  fi
  T="timeout -k 15 -s TERM $lim"  # -k: a bench whose scenes run in child processes is killed 15 s after
  case "$stage" in
    gas)
      $T bash -c 'python3 benchmarks/flow_throughput.py --arch cuda --grids 32x32x116 32x32x64 --steps 50 \
        --warmup 5 && python3 benchmarks/gas_counts.py --arch cuda --grids 32x32x116 32x32x64 --label cuda &&
        python3 benchmarks/launch_cost.py --arch cuda --grids 8x8x16 32x32x116 --blocks 5 &&
        python3 benchmarks/launch_cost.py --arch cuda --per-array' ;;
    grid_ab)  # Taichi launches every dynamic-range loop on CUDA with saturating_grid_dim blocks (default 2 x max
      # blocks per SM x SMs: 8448 of 128 threads on an H100, 1.1M threads for a 119k-cell or an empty loop); the gas
      # step (~450 such loops a step, many tiny or empty) and the DEM substep with 2112 and 1056 against the default.
      # Each width compiles anew (it is part of Taichi's cache key): about 5 minutes; give it a call of its own
      for gd in "" 2112 1056; do echo "== TI_SATURATING_GRID_DIM=${gd:-default}"
        TI_SATURATING_GRID_DIM=$gd $T python3 benchmarks/flow_throughput.py --arch cuda --grids 32x32x116 --steps 30 \
          --warmup 3 --dry
        TI_SATURATING_GRID_DIM=$gd $T python3 benchmarks/dem_substep.py --arch cuda --sizes 1000000 --substeps 300 \
          --repeats 3 --diag-calls 10; done ;;
    coarse)  # the coarse levels of the pressure V-cycle in one launch (app/sim/gas/coarse_cycle.py): on CUDA one block
      # whose threads meet at barriers, a path no CPU test can run: the same systems solved with it and with a launch
      # per level (equal iterations, solutions equal to round-off, scipy's residual); ~30 s. Run it first: every later
      # gas step on CUDA uses that cycle, and where the check fails the later stages of the call run without it
      $T bash -c 'python3 benchmarks/coarse_cycle_check.py --arch cuda --precision float64 &&
        python3 benchmarks/coarse_cycle_check.py --arch cuda --precision float32 --tol 1e-5' ;;
    dem_scan)  # the DEM list build's cell-list scan as one block of threads at barriers (app/sim/dem/scan.py), CUDA's
      # default and a path no CPU test can run: the same lists as the one-thread scan, the cost of a forced build with
      # each, and the substep's tasks by device time (kernel profiler); and the diagnostics record, whose height
      # bin that block finds, against one thread's. Run it first with coarse: where the lists or the records differ,
      # the later stages of the call run with the one-thread scan (FBED_DEM_SCAN=serial); ~1 min
      $T python3 benchmarks/dem_scan_check.py --arch cuda --sizes 1000000 --substeps 40 --repeats 3 --profile ;;
    coarse_ab)  # the gas step without that cycle (a launch down and up per level), to set against gas / gas_profile
      $T bash -c 'python3 benchmarks/flow_throughput.py --arch cuda --grids 32x32x116 32x32x64 --steps 30 --warmup 5 \
          --coarse-block off && python3 benchmarks/gas_counts.py --arch cuda --grids 32x32x116 --coarse-block off \
          --label "coarse block off"' ;;
    coarse_cells)  # the largest level the one-launch cycle takes (FBED_COARSE_CELLS): 0 (a launch down and up per
      # level), 4096 (the default: from 8x8x29 on the Verma grid) and 16384 (from 16x16x58, 14,848 cells a pass for one
      # block of 256 threads: 381 -> 267 tasks a Verma step in the CPU's parallel form, CPU time unchanged); the Verma
      # grid's gas step each way, one process each; ~1 min with the kernels cached
      $T bash -c 'for c in 0 4096 16384; do echo "== FBED_COARSE_CELLS=$c"; FBED_COARSE_CELLS=$c python3 \
          benchmarks/flow_throughput.py --arch cuda --grids 32x32x116 --steps 30 --warmup 5 --dry || exit 1; done' ;;
    mri_frame)  # one synthetic-MRI frame of 1e6 grains: read back and binned in numpy (the probe before 2026-12-06)
      # against binned on the device (DemSolver.slab_volumes, the probe now); exits 1 if the images differ; ~30 s
      $T python3 benchmarks/mri_frame_cost.py --arch cuda --n 1000000 ;;
    rcfd_frame)  # the rCFD probe's grain cells of a 1e6-grain frame: positions read back and numpy (the probe before
      # 2026-12-06) against DemSolver.tracked_cells (the probe now); exits 1 if the integers differ; ~30 s
      $T python3 benchmarks/rcfd_frame_cost.py --device --arch cuda --n 1000000 ;;
    gas_profile)  # where the gas step's time goes on the device: per kernel, tasks and summed task time a step
      $T python3 benchmarks/gas_counts.py --arch cuda --profile --grids 32x32x116 32x32x64 --steps 10 --warmup 3 ;;
    series)
      $T bash -c 'python3 -m app run presets/verma_small.toml --arch cuda --out runs/verma_small --overwrite &&
        python3 benchmarks/series_reads.py presets/verma_small.toml --arch cuda --set run.duration=0.1 --label cuda' ;;
    bench)
      $T python3 benchmarks/dem_throughput.py --arch cuda --sizes 10000 100000 1000000 --substeps 500 ;;
    dem)
      $T bash -c "python3 benchmarks/dem_substep.py --arch cuda --poly --settle 10000 --sizes 1000000 --substeps 500 --repeats 3 --diag-calls 20 &&
        python3 benchmarks/dem_substep.py --arch cuda --sizes 1000000 --substeps 500 --repeats 3 --diag-calls 20 &&
        python3 benchmarks/dem_substep.py --arch cuda --sizes 1000000 --substeps 500 --repeats 3 --shuffle &&
        python3 benchmarks/dem_substep.py --arch cuda --sizes 1000000 --substeps 500 --repeats 3 --shuffle --sort-interval 0 &&
        python3 -m app run presets/verma.toml --arch cuda --out runs/verma_dem --overwrite --set run.duration=0.05 \
          --set 'run.start_from=\"\"'" ;;
    render)
      $T python3 benchmarks/render_cost.py --arch cuda --sizes 260000 1000000 ;;
    small)
      $T python3 -m app run presets/boyce_small.toml --arch cuda --out runs/boyce_small --overwrite --video ;;
    boyce)
      $T python3 -m app run presets/boyce.toml --arch cuda --out runs/boyce --overwrite ;;
    verma)
      $T python3 -m app run presets/verma.toml --arch cuda --out runs/verma --overwrite "${VERMA_FROM[@]}" \
        ${VERMA_SET:-} ;;
    verma_resume)
      $T python3 -m app run --resume runs/verma --arch cuda ;;
    verma_pack)  # the run's last state with its grains' speeds, for a later session (carry it as runs/verma_state.h5),
      # and its planes and series (quantized: 3 s of planes are 17 MB lossless) for pooling the sessions' tables
      pack_moving runs/verma runs/verma_state.h5
      keep_records runs/verma verma_records.h5 planes series --quantize ;;
    verma_start)
      # a guard stop skips the automatic analysis: run it on the data up to the stop
      setsid nohup bash -c "python3 -m app run presets/verma.toml --arch cuda --out runs/verma --overwrite \
        $VERMA_FROM_Q ${VERMA_SET:-}; [ \$? -eq 3 ] && python3 -m app analyze runs/verma" \
        > "$L/verma.log" 2>&1 < /dev/null &
      echo $! > runs/verma.pid; sleep 20; tail -3 "$L/verma.log" ;;
    wait)
      end=$(( $(date +%s) + lim - 15 ))
      while kill -0 "$(cat runs/verma.pid)" 2>/dev/null && [ "$(date +%s)" -lt "$end" ]; do sleep 5; done ;;
    stop)  # SIGTERM: the run checkpoints, ends 'interrupted' and runs its analysis; wait for that
      pkill -TERM -f "^python3 -m app run presets/verma.toml"  # the python, not its bash -c wrapper
      for _ in $(seq 1 $lim); do pgrep -f "^python3 -m app (run|analyze)" > /dev/null || break; sleep 1; done ;;
    accuracy)  # ACC_CASES="cavity umf ..." picks cases; the reference data travel in runs/reference (carry it).
      # --resume: a call cut off by its limit keeps its rows (and runs/prepared its settled beds and reference
      # runs, while the machine stays warm); the next call with the same stage measures only the rest
      $T python3 -m app bench accuracy --size full --arch cuda --out runs/accuracy_full --resume \
        ${ACC_CASES:+--cases $ACC_CASES} ;;
    stiffness)
      $T python3 -m app bench stiffness --size full --arch cuda --out runs/stiffness_full --resume ;;
    mri_prepare)
      $T python3 -m app run presets/mri_poppy_prepare.toml --arch cuda --out runs/mri_prepare --overwrite \
        && python3 -m app pack runs/mri_prepare/bed.h5 runs/mri_bed.h5 --resolution 5e-7 && cp runs/mri_bed.h5 "$OUT/" ;;
    mri_law|mri_sweep_start)
      # from a carried moving state (mri_law only: runs/mri_state_<law>.h5, the end of an earlier session's run of
      # that law, packed with its speeds): the bed goes on fluidized, the inlet at full speed from 0, analysed from
      # 0.02 s (the gas starts afresh and settles within a step). Else from a carried bed: no preparation stage, the
      # clock starts at 0 (inlet ramp 0-0.1 s, steady from 1.1 s, 2 s recorded); else mri_poppy.toml's own
      # start_from (prepared here, cached in runs/prepared)
      law=${MRI_LAW:-koch_hill}
      FROM=()
      if [ "$stage" = mri_law ] && [ -f "runs/mri_state_$law.h5" ]; then
        FROM=(--set 'run.start_from=""' --set "particles.initial_state=\"$PWD/runs/mri_state_$law.h5\"" \
          --set particles.bed_height=0.0 --set 'boundary.bottom.schedule=[[0.0,1.0]]' \
          --set run.duration=2.0 --set output.average_from=0.02)
      elif [ -f runs/mri_bed.h5 ]; then
        FROM=(--set 'run.start_from=""' --set "particles.initial_state=\"$PWD/runs/mri_bed.h5\"" \
          --set particles.bed_height=0.0 --set 'boundary.bottom.schedule=[[0.0,0.0],[0.1,1.0]]' \
          --set run.duration=3.1 --set output.average_from=1.1)
      fi
      if [ "$stage" = mri_law ]; then
        $T python3 -m app run presets/mri_poppy.toml --arch cuda --out runs/mri_$law --overwrite \
          --set coupling.drag=$law "${FROM[@]}" ${MRI_SET:-}
        # its end state with the grains' speeds (bed.h5, or the checkpoint of a run cut at its limit), for a later
        # session to go on from: carry it back as runs/mri_state_<law>.h5 (about 5 MB; MRI_PACK sets the packing)
        pack_moving "runs/mri_$law" "runs/mri_state_$law.h5" ${MRI_PACK:-}
        keep_records "runs/mri_$law" "mri_records_$law.h5" mri slab  # its images, for pooling its sessions
      else
        setsid nohup python3 -m app sweep presets/mri_poppy.toml --arch cuda --out runs/mri_poppy-sweep --overwrite \
          --set coupling.drag=koch_hill,di_felice,gidaspow,beetstra "${FROM[@]}" ${MRI_SET:-} \
          > "$L/mri_sweep.log" 2>&1 < /dev/null &
        echo $! > runs/mri.pid; sleep 20; tail -3 "$L/mri_sweep.log"
      fi ;;
    mri_wait)
      end=$(( $(date +%s) + lim - 15 ))
      while kill -0 "$(cat runs/mri.pid)" 2>/dev/null && [ "$(date +%s)" -lt "$end" ]; do sleep 5; done
      tail -5 runs/mri_poppy-sweep/case-*/log.txt ;;
    mri_rcfd)
      R=runs/mri_${MRI_LAW:-koch_hill}
      $T bash -c "python3 -m app rcfd analyze $R && python3 -m app rcfd run $R --horizon 10 --paths ${RCFD_PATHS:-5} \
        --seed 1 --name poppy_T10" ;;
    mri_compare)
      $T python3 -m app analyze runs/mri_poppy-sweep ;;
    mri_umf)
      $T python3 -m app sweep presets/mri_umf.toml --arch cuda --out runs/mri_umf-sweep --overwrite \
        --set coupling.drag=koch_hill,di_felice,gidaspow,beetstra && python3 -m app analyze runs/mri_umf-sweep ;;
    sweep)
      $T python3 -m app sweep presets/boyce.toml --arch cuda --out runs/boyce-sweep --overwrite --plot bubble_peak_diameter \
        --set boundary.bottom.jet_duration=0.1542,0.0667,0.0514,0.025 --set video.enabled=false ;;
  esac > "$L/$stage.log" 2>&1
  rc=$?
  echo "$stage: exit $rc in $(( $(date +%s) - start )) s (limit $lim s)" | tee -a "$L/stages.txt"
  [ -n "${OUT:-}" ] && { echo "== $stage: exit $rc in $(( $(date +%s) - start )) s (limit $lim s)"
    tail -n 80 "$L/$stage.log"; } >> "$OUT/progress.txt"
  if [ "$stage" = dem_scan ] && [ $rc -ne 0 ]; then  # every later DEM build on CUDA would use the block scan
    export FBED_DEM_SCAN=serial  # the one-thread scan of 1,024-cell blocks instead (the same lists)
    echo "export FBED_DEM_SCAN=serial" >> "$L/fallbacks.env"
    echo "dem_scan: the DEM's block scan failed its check on CUDA: later stages run without it (FBED_DEM_SCAN=serial)" \
      | tee -a "$L/stages.txt"
  fi
  if [ "$stage" = coarse ] && [ $rc -ne 0 ]; then  # every later gas step on CUDA would run that cycle: not trusted
    export FBED_COARSE_CELLS=0  # a launch down and up per level instead (the same results; app/sim/gas/coarse_cycle.py)
    echo "export FBED_COARSE_CELLS=0" >> "$L/fallbacks.env"
    echo "coarse: the one-launch coarse cycle failed its check on CUDA: later stages run without it" \
      "(FBED_COARSE_CELLS=0)" | tee -a "$L/stages.txt"
  fi
done
cp benchmarks/RESULTS.md $L/RESULTS.md
for d in runs/*/; do [ -f "$d/summary.json" ] && cp "$d/summary.json" "$L/$(basename "$d")-summary.json"; done
ls -laR runs > "$L/ls.txt" 2>&1
# one small archive (logs, summaries, analyses; no h5, no videos) and the videos beside it
tar czf "$OUT/results.tgz" --exclude='*.h5' --exclude='*.mp4' --exclude='runs/prepared' runs
for v in runs/*/video.mp4; do [ -f "$v" ] && cp "$v" "$OUT/$(basename "$(dirname "$v")").mp4"; done
ls -la "$OUT"
[ -f "$L/verma.log" ] && tail -n 25 "$L/verma.log"
nvidia-smi --query-gpu=memory.used,utilization.gpu --format=csv
