"""Keep OpenBLAS to one thread while identifying.

Identification works on long vectors (10^4 to 10^5 residuals) and many small matrices.
OpenBLAS splits a product over threads; on a machine whose cores are busy (2 cores shared by
several jobs, as here) waking and joining the threads costs far more than the product: with
the former solver (scipy's trust region with LSMR, all norms and dot products of residual
vectors) a 40-track baseline fit took 8.3 s with the default threads and 5.0 s with one.
The thread count is a property of the loaded library, so it is set through its own C
function, found among the libraries already mapped into the process (Linux), and restored
on exit. Elsewhere this does nothing.
"""

import contextlib
import ctypes

# (setter, getter) of the OpenBLAS builds that numpy and scipy wheels or a system ship.
_SYMBOLS = (
    ('scipy_openblas_set_num_threads64_', 'scipy_openblas_get_num_threads64_'),
    ('scipy_openblas_set_num_threads', 'scipy_openblas_get_num_threads'),
    ('openblas_set_num_threads64_', 'openblas_get_num_threads64_'),
    ('openblas_set_num_threads', 'openblas_get_num_threads'),
)


def _loaded_openblas():
    """(set, get) C function pairs of every OpenBLAS library mapped into this process."""
    try:
        with open('/proc/self/maps') as f:
            paths = {line.split()[-1] for line in f if 'openblas' in line.lower()}
    except OSError:
        return []
    pairs = []
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for setter, getter in _SYMBOLS:
            if hasattr(lib, setter) and hasattr(lib, getter):
                pairs.append((getattr(lib, setter), getattr(lib, getter)))
                break
    return pairs


@contextlib.contextmanager
def blas_threads(n=1):
    """Run the block with at most ``n`` OpenBLAS threads, then restore the previous count."""
    pairs = _loaded_openblas()
    before = [get() for _, get in pairs]
    for set_, _ in pairs:
        set_(n)
    try:
        yield
    finally:
        for (set_, _), count in zip(pairs, before, strict=True):
            set_(count)
