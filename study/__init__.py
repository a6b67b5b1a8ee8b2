"""secuav-study: grids of trials or flights on Dask, resumable, with confidence intervals."""
