"""Files in and out: ``creference-scene/1`` scenes and ``creference-result/1`` results.
"""
