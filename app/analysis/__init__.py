"""Post-processing of void-fraction (porosity) data: pure numpy/scipy/matplotlib/h5py, no Taichi.

- ``app.analysis.bubbles``: generic bubble tools on porosity planes (detection with sub-grid
  interpolation, equivalent diameter, rise velocity by cross-correlation of a plane pair,
  porosity PDF, diameter-height profile, Darton and Werther correlations, single-bubble
  measure on a vertical slab).
- ``app.analysis.verma``: the Verma et al. (2014) post-processing of a run folder
  (``run.h5`` + ``summary.json``) into a comparison table and figures.
"""
