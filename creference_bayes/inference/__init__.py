"""From a model to an estimate: optimiser presets, the log-posterior, the emcee adapter (moves,
coordinates, autocorrelation) and the arviz adapter (summaries, diagnostics, InferenceData).
"""
