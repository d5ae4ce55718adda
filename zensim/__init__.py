"""zensim: a networked MuJoCo robot simulator whose services talk over Zenoh."""

from pkgutil import extend_path

__version__ = "0.1.0"

# The checkout's own `zensim/` folder holds only the command line; the other `zensim.*` packages live in
# services/, schemas/ and robots/ (pyproject's package-dir). Run from the checkout's root (`python -m
# zensim`, pytest), that folder comes first on sys.path and would hide the installed `zensim.common`, ...:
# let the package span every `zensim/` on sys.path, as the editable install's tree is one of them.
__path__ = extend_path(__path__, __name__)
