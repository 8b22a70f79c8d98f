"""Fast paths that must equal the plain computation they replace (helper "speed", issue 21)."""

import numpy as np

from mocapfill.bones.refinement import _bone_sums


def test_bone_sums_equal_dense_jacobian():
    # bones among 4 moved markers (slots 0-3) and fixed ones (-1), with a repeated bone
    ia = np.array([0, 1, -1, 2, 0, 3, 0])
    ib = np.array([1, -1, 2, 3, 2, -1, 1])
    k, n = 4, 5
    rng = np.random.default_rng(1)
    unit = rng.normal(size=(n, len(ia), 3))
    bw = rng.random(len(ia))
    jac = np.zeros((n, len(ia), k, 3))
    for j in range(len(ia)):
        if ia[j] >= 0:
            jac[:, j, ia[j]] += unit[:, j]
        if ib[j] >= 0:
            jac[:, j, ib[j]] -= unit[:, j]
    jac = jac.reshape(n, len(ia), 3 * k)
    grad_sum, hess_sum = _bone_sums(ia, ib, k)
    r = rng.normal(size=(n, len(ia)))
    dense_grad = np.einsum("nbp,b,nb->np", jac, bw, r)
    dense_hess = np.einsum("nbp,b,nbq->npq", jac, bw, jac)
    weighted = unit * bw[None, :, None]
    np.testing.assert_allclose(grad_sum(weighted * r[:, :, None]).reshape(n, 3 * k), dense_grad, atol=1e-12)
    np.testing.assert_allclose(hess_sum(weighted[:, :, :, None] * unit[:, :, None, :]), dense_hess, atol=1e-12)
