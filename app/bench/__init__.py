"""`fbed bench`: the benches, one package.

- :mod:`.stress` (`fbed bench stress`): hostile scenes, each run as its own `fbed run` process with a
  wall-clock limit (the process is the point: a hang, a traceback and the exit code are what is judged).
- :mod:`.accuracy` (`fbed bench accuracy`): run time against error, one cost knob at a time, over the
  verification cases (:mod:`.cases` the record, :mod:`.dem_cases`, :mod:`.gas_cases`, :mod:`.bed_cases`
  the families; :mod:`.bed_figures` what a bed run's outputs say).
- :mod:`.stiffness` (`fbed bench stiffness`): the bed of the bed cases against Young's modulus.
- :mod:`.common`: what the scripts in benchmarks/ share (the machine line, RESULTS.md, the fairness helpers).
"""
