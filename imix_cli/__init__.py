"""imix: evolution strategies with importance mixing (Pourchot, Perrin & Sigaud, 2018).

Library entry points::

    from imix_cli.mixing import DiagonalGaussian, FullGaussian, mix
    from imix_cli.algorithms import OpenES, SNES, CEM, CMAES, make_es
"""

__version__ = "0.1.0"
