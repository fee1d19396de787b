"""`track-dis`: a DIS (IEEE 1278.1, version 7) gateway. Entity State PDUs on UDP become
labelled measurements of the service, and the service's tracks go out as Entity State
PDUs sent the way the standard sends them (docs/gateways.md)."""
