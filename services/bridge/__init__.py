"""`zensim bridge`: joint targets (sliders, scripts) -> motor commands for the sim, held at a fixed rate."""
