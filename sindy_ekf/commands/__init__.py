"""One module per ``sindy-ekf`` command: ``add_arguments(parser)`` and ``run(args)``.

A command parses, calls one library function (:mod:`sindy_ekf.stages`, the report, the
simulator or the preprocessing), prints what it returns and writes the files asked for. Each
module is listed in :data:`sindy_ekf.cli.COMMANDS` and imported only when its command runs.
"""
