"""Stated confidence: reading the stated ranges of a data set (data), fitting a confidence map
(fit), leave-one-out checks (loo) and the reliability report (report)."""
