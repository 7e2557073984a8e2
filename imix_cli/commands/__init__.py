"""The ``imix`` command line (:mod:`imix_cli.commands.cli`) and the subcommands that are not
``imix run``'s machinery: ``imix eval``, ``imix render``, ``imix status``, the process ``imix bench memory``
measures, and the docs' printed outputs (their ``key=value`` parsing: :mod:`imix_cli.keyvalue`). ``imix run`` is :mod:`imix_cli.running`; ``imix plot``
and ``imix bench`` are :mod:`imix_cli.plotting` and :mod:`imix_cli.bench`.
"""
