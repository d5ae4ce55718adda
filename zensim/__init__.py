"""zensim: a networked MuJoCo robot simulator whose services talk over Zenoh."""

__version__ = "0.1.0"
