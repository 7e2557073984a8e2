"""The ``imix`` command line (:mod:`imix_cli.commands.cli`) and the subcommands that are not
``imix run``'s machinery: ``imix eval``, ``imix render``, ``imix status``, their ``key=value``
parsing, and the docs' printed outputs. ``imix run`` is :mod:`imix_cli.running`; ``imix plot``
and ``imix bench`` are :mod:`imix_cli.plotting` and :mod:`imix_cli.bench`.
"""
