"""Figures and tables in the docs, each reproducible with one command; may import anything of the project.

``python -m pipeline.figures sun-positions --out docs/img/sun_positions.png``;
``python -m pipeline.figures.albedo_table``; ``python -m pipeline.figures.contact_sheet``.
"""
