"""Callbacks: the objects a run attaches to its Simulation, each fired on its own schedule.

A callback is called with the Simulation (``sim.add(callback, interval, wall=, at_start=, finish=)``:
every ``interval`` of simulated time, counted in whole steps, and/or every ``wall`` seconds); one with a
``finish(sim, reason)`` is told when the run ends. Writers are attached behind the guard
(``Guard.guarded(writer)``), so nothing non-finite reaches a file.

- ``guard.Guard``: stops an unstable run (raises ``Unstable``) and names the setting to change.
- ``writers``: ``Series`` (run.h5 /series), ``GrainSnapshots`` and ``GasFields`` (frames in run.h5),
  ``Checkpoints`` (checkpoint.h5, ParaView indexes), ``WallCheckpoints`` (on the wall clock),
  ``FinalOutputs`` (the last of each and bed.h5 when the run ends).
- ``bed.BedMeasures``: pressure drop and bed weight per area of a coupled run (a column of the series).
- ``probes.attach_probes``: the [probes] records (app/probes.py, app/probes_mri.py, app/rcfd_probe.py).
- ``progress``: ``Progress`` (bar or log lines), the run's ``log``, the CPU time estimate.
- ``video.VideoFrames``: frames into the mp4; ``renderer_for`` the renderer a run needs.
- ``summary.Summary``: summary.json and summary_units.json when the run ends.

Import each from its module (``from app.callbacks.guard import Guard``): this package imports nothing, so
``app.postprocess`` can use the log without loading the solvers.
"""
