"""Radar captures: the Capture container and readers for real formats."""
