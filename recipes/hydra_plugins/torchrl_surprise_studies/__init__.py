"""The recipes' study settings on Hydra's config search path.

``recipes/<recipe>/setting/`` holds the settings a user chooses among: the
bonuses and the recommended variants. The variants a study measures (a bonus
trained less often, an untrained control, a transfer) live in
``recipes/<recipe>/studies/setting/``; this plugin puts that folder on the
search path of the recipe whose config Hydra loads, so ``+setting=<name>`` finds
either, and each study's commands, labels and run directories stay as they were.
Hydra discovers it in the ``hydra_plugins`` namespace package, which the
recipes' scripts and the tests put on ``sys.path`` with ``recipes/``.
"""

from __future__ import annotations

from pathlib import Path

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin

__all__ = ["StudySettings"]

#: The folder beside a recipe's primary config that holds its study configs.
STUDIES = "studies"


class StudySettings(SearchPathPlugin):
    """Appends ``<primary config dir>/studies`` to the search path, if it exists."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        for element in search_path.get_path():
            path = element.path.removeprefix("file://")
            if element.provider != "main" or "://" in path:
                continue
            studies = Path(path) / STUDIES
            if studies.is_dir():
                search_path.append("torchrl_surprise-studies", f"file://{studies}")
            return
