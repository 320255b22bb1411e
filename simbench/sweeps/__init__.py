"""Many scenarios: a sweep over scenario fields (:mod:`simbench.sweeps.sweep`), the results
store (:mod:`simbench.sweeps.results_db`, DuckDB + Parquet), the sweep report
(:mod:`simbench.sweeps.report`) and the regression gate (:mod:`simbench.sweeps.regression`)."""
