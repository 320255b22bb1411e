"""Any capture system on the bench (issue 14): the inputs another system needs, in files
(:mod:`simbench.pipelines.exchange.inputs`), its results read back and scored
(:mod:`simbench.pipelines.exchange.results`), user commands run as a scenario's pipeline
(:mod:`simbench.pipelines.exchange.command`) and third-party tools in their own environments
(:mod:`simbench.pipelines.exchange.adapters`)."""
