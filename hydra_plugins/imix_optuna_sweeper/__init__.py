"""imix's Optuna sweeper for Hydra (``imix run -m hydra/sweeper=optuna ...``): found by Hydra's plugin scan of the
``hydra_plugins`` namespace package; the logic is in :mod:`imix_cli.commands.search`."""
