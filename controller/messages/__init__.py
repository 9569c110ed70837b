"""Protobuf messages shared by the MCAP recording and the Zenoh payloads (see cheope.proto)."""
