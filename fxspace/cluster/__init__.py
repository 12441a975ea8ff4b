"""Generic clustering: fuzzy c-means and kernel k-means (they know nothing of faces).

Every routine returns a result record with `.result` (a `fxspace.RESULTS` member),
`.num_steps`, `.stats` and `.converged`, and takes `throw=`.
"""

from fxspace.cluster._fcm import FCMResult as FCMResult
from fxspace.cluster._fcm import fcm_memberships as fcm_memberships
from fxspace.cluster._fcm import fcm_objective as fcm_objective
from fxspace.cluster._fcm import kmeanspp_extend as kmeanspp_extend
from fxspace.cluster._fcm import kmeanspp_init as kmeanspp_init
from fxspace.cluster._fcm import squared_distances as squared_distances
from fxspace.cluster._fcm_blocks import precompile as precompile_fcm_blocks
from fxspace.cluster._fcm_front import fuzzy_cmeans as fuzzy_cmeans
from fxspace.cluster._fcm_sparse import SparseFCMResult as SparseFCMResult
from fxspace.cluster._kernel_kmeans import KernelKMeansResult as KernelKMeansResult
from fxspace.cluster._kernel_kmeans import gaussian_kernel as gaussian_kernel
from fxspace.cluster._kernel_kmeans import kernel_kmeans as kernel_kmeans
from fxspace.cluster._kernel_kmeans import kernel_kmeans_gram as kernel_kmeans_gram
from fxspace.cluster._kernel_kmeans import median_gamma as median_gamma
from fxspace.cluster._kmeanspp import pad_rows as pad_rows

__all__ = [
    "FCMResult",
    "fcm_memberships",
    "fcm_objective",
    "fuzzy_cmeans",
    "precompile_fcm_blocks",
    "kmeanspp_extend",
    "pad_rows",
    "kmeanspp_init",
    "squared_distances",
    "SparseFCMResult",
    "KernelKMeansResult",
    "gaussian_kernel",
    "kernel_kmeans",
    "kernel_kmeans_gram",
    "median_gamma",
]
