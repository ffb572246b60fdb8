"""The learner: off-policy VICE-RAQ (soft actor-critic from pixels with a learned reward) and its baselines."""
