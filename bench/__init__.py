"""Measurements of the product (speed, limits, the paper's figures): scripts that build what
they measure through the product's own factories and spec fields, importable as `bench.<name>`
(`python bench/<name>.py` and `python -m bench.<name>` run the same code)."""
