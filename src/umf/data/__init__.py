"""Datasets, adapters and the multi-person scene corpus."""
