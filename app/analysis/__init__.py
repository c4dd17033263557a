"""Post-processing of void-fraction (porosity) data: pure numpy/scipy/matplotlib/h5py, no Taichi.

- ``app.analysis.bubbles``: generic bubble tools on porosity planes (detection with sub-grid
  interpolation, equivalent diameter, porosity PDF, diameter-height profile, Darton and Werther
  correlations, single-bubble measure on a vertical slab, bubbles followed through 3-D frames).
- ``app.analysis.rise``: rise velocities between a plane pair (cross-correlation; noses and tails).
- ``app.analysis.correlations``: the Darton and Werther bubble-diameter correlations (also as
  ``bubbles.darton`` / ``bubbles.werther``).
- ``app.analysis.verma``: the Verma et al. (2014) post-processing of a run folder
  (``run.h5`` + ``summary.json``) into a comparison table and figures (``verma_figures``);
  ``verma_pool``: several runs of the case pooled.
- ``app.analysis.boyce``: the Boyce et al. single-bubble rig.
- ``app.analysis.mri``: the MRI poppy-seed study's pipeline on slab images (its statistics in
  ``mri_stats``, its tables in ``mri_report``, its figures in ``mri_figures``).
- ``app.analysis.pooling``: the check that several runs are one case (`fbed analyze RUN RUN --out`).
- ``app.analysis.umf``: fluidization curves and U_mf.
"""
