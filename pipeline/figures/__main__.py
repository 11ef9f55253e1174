"""``python -m pipeline.figures sun-positions --out FILE.png``: the README's figure."""

from pipeline.figures.sun_positions import main

main()
