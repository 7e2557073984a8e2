"""The Hydra side of imix's Optuna sweeper: a :class:`hydra.plugins.sweeper.Sweeper` whose work is done by
:class:`imix_cli.commands.search.Search` (Optuna's ask/tell API). Imports nothing of Optuna until a search starts: Hydra
imports every plugin module at start-up."""

from __future__ import annotations

from typing import Any

from hydra.plugins.sweeper import Sweeper


class ImixOptunaSweeper(Sweeper):
    def __init__(self, **settings: Any) -> None:
        self.settings = settings
        self.search = None

    def setup(self, *, hydra_context, task_function, config) -> None:
        from imix_cli.commands.search import Search

        self.search = Search(self.settings, hydra_context, task_function, config)

    def sweep(self, arguments: list[str]) -> Any:
        assert self.search is not None
        return self.search.sweep(arguments)
