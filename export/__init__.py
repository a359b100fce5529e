"""Student checkpoint -> ``student.onnx`` (DDIM unrolled, metadata inside), parity/latency check, int8; and
back (``export.recover``)."""
