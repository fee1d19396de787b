"""The numbers of IEEE 1278.1 the gateway keeps (symbolic names of the standard's
Annex: DIS parameters), and the gateway's own defaults beside them: the one place
`track-dis` takes them from."""

from __future__ import annotations

import math

PORT = 3000  # UDP port by convention
EXERCISE = 1
DRA_POS_THRSH = 1.0  # m: dead-reckoned position off by more than this: send
DRA_ORIENT_THRSH = math.radians(3.0)  # rad: the same for orientation
HBT_ESPDU = 5.0  # s: Entity State heartbeat
HBT_TIMEOUT_MPLIER = 2.4  # an entity is gone after this many heartbeats without a PDU
TIMEOUT = HBT_TIMEOUT_MPLIER * HBT_ESPDU  # 12 s
TIMESTAMP_WINDOW = 5.0  # s: absolute timestamps accepted this far ahead or behind
MTU = 1400  # octets: the smallest MTU a PDU must fit
ALL_ENTITIES = 0xFFFF  # entity number meaning every entity of a site:application

# the gateway's own PDUs (out): its site:application, which the in side never takes back
OWN_SITE = 0xFFFE
OWN_APPLICATION = 0xFFFE
ENTITY_TYPE = "1.2.0.0"  # platform, air; country and category unknown (SISO-REF-010)
FORCE = 0  # other (1 friendly, 2 opposing, 3 neutral)

# dead-reckoning algorithms (UID 44): name -> (number, with acceleration, rotating)
DR_ALGORITHMS = {"fpw": (2, False, False), "rpw": (3, False, True),
                 "rvw": (4, True, True), "fvw": (5, True, False)}
