"""`zensim loco`: the walking controller, one per robot, for every front end (docs in README.md)."""
