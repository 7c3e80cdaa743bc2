"""One module per technique's paper reproductions (``dyngi reproduce NAME``).

Each module registers its experiments with
:func:`dyngi.experiments.reproduce.register_experiment`; :mod:`dyngi.experiments.reproduce` imports
every module of this package before it lists or runs experiments.
"""
