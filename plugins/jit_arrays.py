"""Host arrays handed to Dr.Jit kernels: `mitsonar._jit.upload` (shared with the receiver chain's
kernel, `mitsonar.receiver.jitchain`)."""
from mitsonar._jit import upload

__all__ = ["upload"]
