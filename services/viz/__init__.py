"""`zensim viz`: the web viewer (meshcat) with joint sliders, sim controls and status, over Zenoh."""
