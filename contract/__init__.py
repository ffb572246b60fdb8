"""What the web app and the learner both use: the store and its models, the run configuration and its validation,
the algorithm table, the env ids and presets, the image codec, the checkpoint locations and the settings.

It imports neither `app` nor `learner` (tests/test_import_layers.py), so the two meet only here.
"""
