"""Student checkpoint -> ``student.onnx`` (DDIM unrolled, metadata inside), parity/latency check, int8."""
