"""One scenario: its frames through a capture system, scored against the ground truth,
reported (:mod:`simbench.pipelines.run`, ``simbench run``): the marker pipeline, the
calibration session (:mod:`simbench.pipelines.calibration`) and the colour shirt
(:mod:`simbench.pipelines.shirt`, its pose database :mod:`simbench.pipelines.shirt_database`).
This is the only package that holds both the ground truth and a pipeline's output."""
