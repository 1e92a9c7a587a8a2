"""The analysis: transactions from dissected frames, the rows of the tables, the capture loop, the
parallel paths and the public API (`api.analyze`, `api.Analysis`)."""
