"""``imix run``'s command line and ``conf/`` composed by Hydra and checked into an immutable RunSpec."""
