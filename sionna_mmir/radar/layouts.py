"""Antenna layout tables, ``(azimuth, elevation)`` in lambda/2 at 76.8 GHz.

Sources: TI MMWCAS-RF-EVM module parameters (device Tx 1..12, Rx 1..16), as
quoted in the measured-data README and, re-indexed, in ColoRadar's
``cascade/antenna_cfg.txt``; TI AWR1843BOOST user guide (Tx2 raised by lambda/2).
"""

MMWCAS_TX = [(11, 6), (10, 4), (9, 1), (32, 0), (28, 0), (24, 0), (20, 0), (16, 0),
             (12, 0), (8, 0), (4, 0), (0, 0)]
MMWCAS_RX = [(11, 0), (12, 0), (13, 0), (14, 0), (50, 0), (51, 0), (52, 0), (53, 0),
             (46, 0), (47, 0), (48, 0), (49, 0), (0, 0), (1, 0), (2, 0), (3, 0)]

AWR1843_TX = [(0, 0), (2, 1), (4, 0)]
AWR1843_RX = [(0, 0), (1, 0), (2, 0), (3, 0)]
