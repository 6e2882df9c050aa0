import math

import pytest
import torch

from umf import rotations as R

torch.manual_seed(0)


def random_rotations(n: int) -> torch.Tensor:
    return R.quat_to_matrix(R.quat_normalize(torch.randn(n, 4, dtype=torch.float64)))


def test_quat_matrix_round_trip():
    m = random_rotations(500)
    assert torch.allclose(R.quat_to_matrix(R.matrix_to_quat(m)), m, atol=1e-10)
    # proper rotations
    assert torch.allclose(
        m @ m.transpose(-1, -2), torch.eye(3, dtype=m.dtype).expand_as(m), atol=1e-12
    )
    assert torch.allclose(torch.linalg.det(m), torch.ones(500, dtype=m.dtype))


def test_quat_mul_matches_matrix_product_and_rotate():
    a, b = R.quat_normalize(torch.randn(2, 100, 4, dtype=torch.float64))
    assert torch.allclose(
        R.quat_to_matrix(R.quat_mul(a, b)), R.quat_to_matrix(a) @ R.quat_to_matrix(b)
    )
    v = torch.randn(100, 3, dtype=torch.float64)
    assert torch.allclose(R.quat_rotate(a, v), (R.quat_to_matrix(a) @ v[..., None])[..., 0])


def test_axis_angle_known_value_and_round_trip():
    # +90 degrees about +Y takes +Z to +X (right-handed)
    m = R.axis_angle_to_matrix(torch.tensor([0.0, math.pi / 2, 0.0], dtype=torch.float64))
    assert torch.allclose(
        m @ torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64),
        torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64),
        atol=1e-12,
    )
    aa = torch.randn(300, 3, dtype=torch.float64)
    aa = aa / aa.norm(dim=-1, keepdim=True) * torch.rand(300, 1, dtype=torch.float64) * 3.0
    assert torch.allclose(R.matrix_to_axis_angle(R.axis_angle_to_matrix(aa)), aa, atol=1e-8)
    assert torch.allclose(R.axis_angle_to_quat(torch.zeros(3)), torch.tensor([1.0, 0, 0, 0]))


def test_sixd_round_trip_and_gram_schmidt():
    m = random_rotations(200)
    d6 = R.matrix_to_6d(m)
    assert d6.shape == (200, 6)
    assert torch.allclose(d6[:, :3], m[:, :, 0])  # first column first
    assert torch.allclose(R.sixd_to_matrix(d6), m, atol=1e-12)
    # a perturbed 6-D vector still maps to a proper rotation
    m2 = R.sixd_to_matrix(d6 + 0.1 * torch.randn_like(d6))
    assert torch.allclose(torch.linalg.det(m2), torch.ones(200, dtype=m.dtype))


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_euler_round_trip_all_orders(order):
    ang = (torch.rand(400, 3, dtype=torch.float64) - 0.5) * torch.tensor([340.0, 170.0, 340.0])
    m = R.euler_to_matrix(ang, order)
    back = R.matrix_to_euler(m, order)
    assert torch.allclose(back, ang, atol=1e-7)
    # gimbal lock still gives the same matrix
    lock = ang.clone()
    lock[:, 1] = 90.0
    m = R.euler_to_matrix(lock, order)
    assert torch.allclose(R.euler_to_matrix(R.matrix_to_euler(m, order), order), m, atol=1e-9)


def test_euler_is_intrinsic_in_listed_order():
    ang = torch.tensor([30.0, 40.0, 50.0], dtype=torch.float64)
    rz = R.euler_to_matrix(torch.tensor([30.0, 0, 0], dtype=torch.float64), "ZXY")
    rx = R.euler_to_matrix(torch.tensor([0.0, 40.0, 0], dtype=torch.float64), "ZXY")
    ry = R.euler_to_matrix(torch.tensor([0.0, 0, 50.0], dtype=torch.float64), "ZXY")
    assert torch.allclose(
        rz[:2, :2], torch.tensor([[0.75**0.5, -0.5], [0.5, 0.75**0.5]], dtype=rz.dtype)
    )
    assert torch.allclose(R.euler_to_matrix(ang, "ZXY"), rz @ rx @ ry)
    with pytest.raises(ValueError):
        R.euler_to_matrix(ang, "XXY")


def test_quat_between_including_antiparallel():
    u = torch.randn(200, 3, dtype=torch.float64)
    v = torch.randn(200, 3, dtype=torch.float64)
    v[:10] = -u[:10]  # antiparallel
    q = R.quat_between(u, v)
    got = R.quat_rotate(q, u / u.norm(dim=-1, keepdim=True))
    assert torch.allclose(got, v / v.norm(dim=-1, keepdim=True), atol=1e-9)
