"""One module per ``sindy-ekf`` command: ``add_parser(sub, common)`` and ``run(args)``."""
