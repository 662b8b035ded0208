"""The likelihood models (the paper's cost, the metrology model) and their shared parameter space.
NumPy and SciPy only.
"""
