"""Recurrence CFD (rCFD): long-time passive transport from a short recorded CFD-DEM run.

Plain numpy/scipy (no Taichi). The recording probe (app/rcfd_probe.py) writes rcfd.h5 beside
run.h5; this package reads it back and works on it:

- ``database``: the rcfd.h5 layout, the Database reader, the tag expressions (``x<0``).
- ``recurrence``: the recurrence matrix (a Gram matrix in chunks), spectra and the dominant
  period, the mean distance against lag, the database-length check, the Taylor time scale.
- ``paths``: seeded Markov paths through the recorded frames.
- ``transport``: the solids tracer moved by the recorded shift operators (exactly
  conservative, bounded), the stitch at jumps, the mixing index; ``matching``/``flowmatch``: the
  grain tracer's jumps, grains paired by position (a dense assignment, or routed along a flow).
- ``commands``: ``fbed rcfd analyze|run``; ``validate``: ``fbed rcfd validate``.

Method: Lichtenegger & Pirker 2016 (CES 153:394) for the recurrence statistics and paths;
Pirker & Lichtenegger 2018 (CES 188:65) for transport by cell-to-cell shifts;
the design note ../shared/rcfd.md.
"""
