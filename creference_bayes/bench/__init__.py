"""Measuring the package: the scene simulator, the benchmark, its report and figures, the peer
solver (PoseLib) and the Cramér–Rao bound.
"""
