"""`zensim unitree`: Unitree's low-level DDS interface (unitree_sdk2's rt/lowcmd, rt/lowstate) for zensim."""
