"""Design analysis: what a recording determines, before any estimator: still periods and turns
(segmentation, stillness, turn windows, gaps), holds and their noise, outliers, pose
directions and coverage, clipping, channel faults, the sphere's quality, the noise read from
an Allan deviation. Pure: arrays in, dataclasses out."""
