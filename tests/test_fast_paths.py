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


def _svd_rotation(A):
    U, _, Vt = np.linalg.svd(A)
    s = np.sign(np.linalg.det(U @ Vt))
    s[s == 0] = 1.0
    U[:, :, 2] *= s[:, None]
    return U @ Vt


def test_nearest_rotation_equals_svd_kabsch():
    from mocapfill.engines.body_frame import nearest_rotation

    rng = np.random.default_rng(2)
    shape = rng.normal(size=(6, 3)) * 100
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    rot = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                    2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                    2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1).reshape(-1, 3, 3)
    A = np.swapaxes(shape[None] @ rot + rng.normal(size=(200, 6, 3)), 1, 2) @ shape
    A[0] = -A[0]  # a reflection: the SVD's sign rule
    A[1, :, 2] = 0.0  # rank-deficient
    A[2] = 0.0
    A = np.concatenate([A, rng.normal(size=(100, 3, 3))])
    np.testing.assert_allclose(nearest_rotation(A), _svd_rotation(A), atol=1e-12)
    np.testing.assert_allclose(nearest_rotation(A[:5]), _svd_rotation(A[:5]), atol=1e-12)


def test_nearest_rotation_of_planar_shapes_equals_svd_kabsch():
    """Three anchors (a planar shape: the cross-covariance has rank 2) take the quaternion eigenvector, not the SVD
    (the largest eigenvalue stays apart from the next), and give the SVD's proper rotation, rotated shapes and
    reflected ones alike."""
    from mocapfill.engines.body_frame import nearest_rotation

    rng = np.random.default_rng(3)
    shape = rng.normal(size=(3, 3)) * 100
    shape -= shape.mean(axis=0)
    rot = np.linalg.qr(rng.normal(size=(300, 3, 3)))[0]
    rot[:150] *= np.sign(np.linalg.det(rot[:150]))[:, None, None]  # proper rotations, then reflections
    moved = shape[None] @ rot + rng.normal(size=(300, 3, 3))
    moved -= moved.mean(axis=1, keepdims=True)
    A = np.swapaxes(moved, 1, 2) @ shape
    assert np.all(np.abs(np.linalg.det(A)) <= 1e-6 * np.linalg.norm(A, axis=(1, 2)) ** 3)
    np.testing.assert_allclose(nearest_rotation(A), _svd_rotation(A), atol=1e-10)


def test_nearest_rotation_of_nearly_collinear_shapes_equals_svd_kabsch():
    """A nearly collinear shape (the rotation about its axis barely determined) takes the SVD; the answer is the
    SVD's either way."""
    from mocapfill.engines.body_frame import nearest_rotation

    rng = np.random.default_rng(4)
    line = np.outer(np.linspace(-1.0, 1.0, 5), [100.0, 20.0, -50.0]) + rng.normal(size=(5, 3)) * 1e-3
    line -= line.mean(axis=0)
    rot = np.linalg.qr(rng.normal(size=(100, 3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))[:, None, None]
    moved = line[None] @ rot + rng.normal(size=(100, 5, 3)) * 1e-3
    A = np.swapaxes(moved - moved.mean(axis=1, keepdims=True), 1, 2) @ line
    np.testing.assert_allclose(nearest_rotation(A), _svd_rotation(A), atol=1e-9)
