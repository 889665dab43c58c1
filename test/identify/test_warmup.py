"""The demo's kernel warm-up is skipped once its marker is in the kernel cache directory."""
from dea_ros.identify.warmup import MARKER, kernels_cached
from dea_ros.solvers.jit import CACHE_DIR


def test_marker_in_the_cache_directory_means_cached(tmp_path):
    assert not kernels_cached(tmp_path)
    (tmp_path / MARKER).write_text("warm-up completed in 1.0 s\n")
    assert kernels_cached(tmp_path)
    assert isinstance(kernels_cached(), bool) and CACHE_DIR  # the default: this process's kernel cache
