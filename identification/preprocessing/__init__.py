"""Preprocessing: a tracker campaign (data contract part 1) to a trajectory campaign (part 2).

Thesis 5.1 (survey: transform and body frame), 5.2 (clock synchronisation on the trigger gaps,
the AT960 timing error, turning-hub eccentricity, poses) and 5.3.5 (smoothing splines and
body-frame velocities). :func:`~identification.preprocessing.campaigns.open_campaign` opens
either kind of campaign as a trajectory campaign.
"""
