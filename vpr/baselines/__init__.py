"""Baselines evaluated in the same harness as rSHOSM: pairwise comparison and SeqSLAM."""
