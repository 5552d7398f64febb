"""The results tools: a sweep's aggregation (``recipes/results/aggregate.py``) and
the surprise heatmaps (``recipes/results/heatmap.py``), run as scripts."""
