"""The replay server: a thin gRPC servicer over a pure-Python core of tables (samplers, rate
limiters, slots, signatures), with write-ahead durability and Prometheus metrics."""
