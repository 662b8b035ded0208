"""Files in and out: ``creference-scene/1`` scenes and ``creference-result/1`` results, and the
annotation tools' exports (Label Studio JSON, CVAT for images 1.1 XML) converted to scenes.
"""
