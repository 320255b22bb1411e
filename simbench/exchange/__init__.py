"""Any capture system on the bench (issue 14): the inputs another system needs, in files
(:mod:`simbench.exchange.inputs`), its results read back and scored
(:mod:`simbench.exchange.results`), user commands run as a scenario's pipeline
(:mod:`simbench.exchange.command`) and third-party tools in their own environments
(:mod:`simbench.exchange.adapters`)."""
