"""A small learner of the labels (docs/learning.md)."""
