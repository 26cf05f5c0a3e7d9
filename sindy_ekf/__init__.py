"""sindy-ekf: identified SINDy driving dynamics of a skid-steered robot as the process model of
an EKF and a factor graph, benchmarked against laser-tracker truth.

The package is split in three, as the data flow is:

- :mod:`simulation`: a faithful simulator of the robot and of the laser-tracker campaign
  (writes the data contract), and the degraded-GNSS generator;
- :mod:`identification`: raw bags to poses and body-frame states (thesis ch. 5.1, 5.2) and
  integral SINDy with control (thesis 5.3);
- :mod:`sindy_ekf`: process models, EKF, factor graph, benchmark, diagnosis, report and the
  ``sindy-ekf`` command line.

Importing this package is cheap: heavy modules are imported where they are used.
"""

__version__ = "0.1.0"
