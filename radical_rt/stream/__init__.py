"""One vehicle's stream: input decoding and checks, queues, releases to the engine, telemetry."""
