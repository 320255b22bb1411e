"""Speed figures, each with a reference measured in the same run (``simbench bench ...``):
the renderer (:mod:`simbench.benchmarks.render`), the marker pipeline
(:mod:`simbench.benchmarks.pipeline`) and the colour-shirt pipeline
(:mod:`simbench.benchmarks.shirt`)."""
