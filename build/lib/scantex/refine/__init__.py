"""Refinement after the field: the paper's Vision Transformer, trained self-supervised on the scan's own
views, and fusion of the refined views back into the atlas.

``refine_colour`` (:mod:`scantex.refine.stage`) is what the pipeline calls; :class:`ViTRefiner`,
:func:`fit_refiner` and :func:`fuse_views` are the pieces. Nothing here downloads weights.
"""
