"""The MCAP contract: topic names, the project's protobuf schemas, a writer that keeps a log
atomic, and a reader with random access by frame and validation. Never needs the simulator."""
