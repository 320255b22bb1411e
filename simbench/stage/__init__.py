"""A scenario becomes a stage: scene, motion, cameras, lights, the frame renderer and the
frame times (:mod:`simbench.stage.stage`, :mod:`simbench.stage.capture`), rendered into
frames and exact ground truth (:mod:`simbench.stage.rendering`,
:mod:`simbench.stage.ground_truth`); the calibration session rendered with the same rig
(:mod:`simbench.stage.calibration_scene`)."""
