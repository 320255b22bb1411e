"""Reproductions of published experiments on the bench: seed 000's tracker study
(:mod:`simbench.studies.trackers`, ``simbench study trackers``)."""
