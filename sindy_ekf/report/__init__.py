"""The HTML report, a consumer of the chain (:mod:`sindy_ekf.stages.chain`).

:mod:`~sindy_ekf.report.html` the page and :func:`~sindy_ekf.report.html.build_report`,
:mod:`~sindy_ekf.report.sections` one section per stage, :mod:`~sindy_ekf.report.blocks` the
section with its notes, tables and figures, :mod:`~sindy_ekf.report.figures` the figures no
stage draws itself, :mod:`~sindy_ekf.report.bag_facts` what reading the bags found, in words,
:mod:`~sindy_ekf.report.demo` the demo (a simulated campaign through the whole chain).
"""
