"""Generated gRPC code for protos/graft/replay/v1/replay.proto (make proto)."""
