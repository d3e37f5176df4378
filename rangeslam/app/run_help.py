"""The text of ``rangeslam run --help``: what RIRS can be, and the beacon log's format.

Laid out by hand (the parser keeps its line breaks): the file forms are a table and the beacon
log's records an example. The format's full notes are :mod:`rangeslam.datasets.beacon_log`'s;
the README's "Beacon logs" section is the same example.
"""

from __future__ import annotations

__all__ = ["RUN_DESCRIPTION", "RUN_EPILOG"]

RUN_DESCRIPTION = """\
The room, a moving microphone's trajectory, or a robot's path, from your files.
Exit 0 converged, 1 not converged, 2 bad input.

RIRS of one loudspeaker:
  room.npz                rirs (M, L), fs; optionally mics, step_bounds, c, keyframes,
                          and ground truth (source, room_size, trajectory, ...)
  room.sofa               a SOFA file of impulse responses (AES69, read with sofar):
                          every receiver is a microphone, at the position it carries
  array.wav               one multichannel WAV: channel m is microphone m's RIR
  mics/                   a directory of mono WAVs, one per microphone, in natural
                          order of names (mic2.wav before mic10.wav)
  m0.wav m1.wav ...       mono WAVs, one per microphone, in the order given
RIRS of several loudspeakers at the same microphones (their walls fitted jointly):
  src0.npz src1.npz ...   one .npz (or .sofa) per loudspeaker
  src0.wav src1.wav ...   one multichannel WAV per loudspeaker (channel m: microphone m)
  src0/ src1/ ...         a directory of mono WAVs per loudspeaker
With microphone positions (--mics, or the npz's mics): the room (walls, loudspeakers).
With bounds on each step of one moving microphone (--step-bounds): its trajectory and
the landmarks. Sample 0 of every RIR is the emission (else --unknown-emission).
--mics, --step-bounds, --keyframes and --excitation as .csv / .txt: comma- or
space-separated numbers, '#' comments, a first row of column names (a header such as
x,y,z) skipped.

Or one beacon log, a .csv or .txt given alone: odometry and ranges to radio beacons;
the robot's path and the beacons (see below). Or one PyFG file (.pyfg, CORA's range-aided
SLAM problems): every robot's trajectory (TUM) and the landmarks, scored against the
file's reference values."""

RUN_EPILOG = """\
beacon log (rangeslam.datasets.beacon_log): one record a line, the first field says
which; '#' starts a comment; a first row of column names is skipped.

  # range_sigma = 0.05                    settings (optional): the ranges' noise [m],
  # odometry_sigma = 0.0005 0.0005 0.002  odometry noise a step: along, across [m],
  # wheel_base = 0.35                     heading [rad]; wheel base [m] (for wheels)
  start, 0.0                              time [s] of pose 0
  odometry, 0.2, 0.01, 0.001              a step: time [s] of the pose it reaches,
                                          distance [m], heading change [rad]
  speed, 0.4, 0.05, 0.005                 or: time, v [m/s], omega [rad/s]
  wheels, 0.6, 0.049, 0.051               or: time, left and right wheel speeds [m/s]
  range, 0.2, 7, 1.234                    time [s], beacon id (integer >= 0), range [m]
  truth, 0.2, 0.01, 0.0, 0.001            optional, every pose: time, x, y [m], heading
  beacon, 7, 1.5, -0.3, known             optional: id, x, y [m], known (given to the
                                          estimator, two or more) or truth (scored)

A range joins the first pose at or after its time. Any other '# name = value' is
refused (a typo would change the result). Without range_sigma the noise comes from the
ranges themselves. The ranges are fitted with a Huber kernel; the summary counts the
outliers (ranges more than 3 sigma off the fit) per beacon and names their lines."""
