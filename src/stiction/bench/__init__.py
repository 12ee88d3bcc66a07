"""Benchmarks that ship with the package (``stiction bench ...``): each prints JSON rows and can
write CSV + PNG. ``scaling``: cost per step against contact count (issue: scale)."""
