"""Workflows over the protocols: the paper's experiments and report, ensembles on Dask, the
Table's benchmark, figures, and a protocol run as a checkpointed trajectory with its table."""
