"""Comparison harness: mmIR vs the Sionna RT baseline, like for like.

``ground_truth``  render a benchmark scene's ground-truth capture
``harness``       fit both models to a capture, metrics, timings
``report``        Table 2 as Markdown / CSV, RA panels and loss curves (PNG)
"""
