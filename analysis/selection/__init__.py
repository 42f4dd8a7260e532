"""The learner-selection tools: Table 1's learner (``learner_search``) and each ball-catching
method's (``ballcatch_tuning``); each runs as ``python -m analysis.selection.<name>``."""
