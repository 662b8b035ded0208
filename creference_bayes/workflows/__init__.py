"""Work over many scenes and targets, built on :func:`creference_bayes.estimate`.
"""
