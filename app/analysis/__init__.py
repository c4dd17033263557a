"""Post-processing of void-fraction (porosity) data: pure numpy/scipy/matplotlib/h5py, no Taichi.

- ``app.analysis.bubbles``: generic bubble tools on porosity planes (detection with sub-grid
  interpolation, equivalent diameter, rise velocity by cross-correlation of a plane pair,
  porosity PDF, diameter-height profile, Darton and Werther correlations, single-bubble
  measure on a vertical slab).
- ``app.analysis.correlations``: the Darton and Werther bubble-diameter correlations (also as
  ``bubbles.darton`` / ``bubbles.werther``).
- ``app.analysis.verma``: the Verma et al. (2014) post-processing of a run folder
  (``run.h5`` + ``summary.json``) into a comparison table and figures (``verma_figures``).
- ``app.analysis.boyce``: the Boyce et al. single-bubble rig.
- ``app.analysis.mri``: the MRI poppy-seed study's pipeline on slab images (its statistics in
  ``mri_stats``, its tables in ``mri_report``, its figures in ``mri_figures``); ``app.analysis.umf``: fluidization curves and U_mf.
"""
