"""URDF parsing and vectorised recursive Newton-Euler inverse dynamics of the G1 left arm.

Fixed pelvis (world z up, gravity -z), waist joints locked at 0, so the chain starts at the torso
frame with identity orientation. The seven left-arm joints drive bodies 0..6; every link below
left_wrist_yaw_link (palm, Dex3-1 fingers at their zero angles) is lumped into body 6 as one rigid
body, which is what the hand is when its fingers do not move.
"""
import os
import xml.etree.ElementTree as ET

import numpy as np

from . import shared_dir

ARM_JOINTS = [
    "left_shoulder_pitch_joint", "left_shoulder_roll_joint", "left_shoulder_yaw_joint",
    "left_elbow_joint", "left_wrist_roll_joint", "left_wrist_pitch_joint", "left_wrist_yaw_joint",
]
G = 9.81

DEFAULT_URDF = os.path.join(shared_dir(), "g1_description", "g1_29dof_with_hand_rev_1_0.urdf")


def rpy_matrix(r, p, y):
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _vec(s, default="0 0 0"):
    return np.array([float(v) for v in (s or default).split()])


class Body:
    """Rigid body: mass m, centre of mass c (body frame), inertia Ic about the COM (body frame)."""

    def __init__(self, m, c, Ic):
        self.m, self.c, self.Ic = float(m), np.asarray(c, float), np.asarray(Ic, float)

    @staticmethod
    def combine(parts):
        m = sum(p.m for p in parts)
        c = sum(p.m * p.c for p in parts) / m
        Ic = np.zeros((3, 3))
        for p in parts:
            d = p.c - c
            Ic += p.Ic + p.m * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
        return Body(m, c, Ic)

    def moved(self, R, p):
        """The same body expressed in a parent frame where this body's frame is (R, p)."""
        return Body(self.m, R @ self.c + p, R @ self.Ic @ R.T)


class ArmModel:
    def __init__(self, urdf=DEFAULT_URDF, payload_kg=0.0, payload_pos=(0.12, 0.0, 0.0)):
        root = ET.parse(urdf).getroot()
        self.urdf = os.path.basename(urdf)
        joints = {j.get("name"): j for j in root.findall("joint")}
        links = {l.get("name"): l for l in root.findall("link")}
        children = {}
        for j in root.findall("joint"):
            children.setdefault(j.find("parent").get("link"), []).append(j)

        def link_body(name):
            inert = links[name].find("inertial")
            if inert is None:
                return None
            o = inert.find("origin")
            c = _vec(o.get("xyz") if o is not None else None)
            R = rpy_matrix(*_vec(o.get("rpy") if o is not None else None))
            i = inert.find("inertia").attrib
            I = np.array([[float(i["ixx"]), float(i["ixy"]), float(i["ixz"])],
                          [float(i["ixy"]), float(i["iyy"]), float(i["iyz"])],
                          [float(i["ixz"]), float(i["iyz"]), float(i["izz"])]])
            return Body(float(inert.find("mass").get("value")), c, R @ I @ R.T)

        def subtree(name):
            """Body of link `name` plus all descendants at zero joint angle, in `name`'s frame."""
            parts = [b for b in [link_body(name)] if b is not None]
            for j in children.get(name, []):
                o = j.find("origin")
                R = rpy_matrix(*_vec(o.get("rpy")))
                p = _vec(o.get("xyz"))
                parts.append(subtree(j.find("child").get("link")).moved(R, p))
            return Body.combine(parts)

        self.R0, self.p, self.axis, self.lower, self.upper, self.bodies = [], [], [], [], [], []
        for k, jn in enumerate(ARM_JOINTS):
            j = joints[jn]
            o = j.find("origin")
            self.R0.append(rpy_matrix(*_vec(o.get("rpy"))))
            self.p.append(_vec(o.get("xyz")))
            ax = _vec(j.find("axis").get("xyz"))
            assert np.count_nonzero(ax) == 1 and abs(ax.sum()) == 1.0, ax
            self.axis.append(int(np.argmax(np.abs(ax))))
            assert ax[self.axis[-1]] == 1.0
            lim = j.find("limit")
            self.lower.append(float(lim.get("lower")))
            self.upper.append(float(lim.get("upper")))
            child = j.find("child").get("link")
            if k < 6:
                b = link_body(child)
            else:
                b = subtree(child)  # wrist yaw link + palm + fingers, one rigid body
            self.bodies.append(b)
        self.hand_mass = self.bodies[6].m
        self.payload_kg = float(payload_kg)
        self.payload_pos = np.asarray(payload_pos, float)
        if payload_kg > 0:
            # point mass held at the hand centre (between palm and finger roots), wrist-yaw frame
            self.bodies[6] = Body.combine([self.bodies[6], Body(payload_kg, self.payload_pos, np.zeros((3, 3)))])
        self.m = np.array([b.m for b in self.bodies])
        self.c = np.array([b.c for b in self.bodies])
        self.Ic = np.array([b.Ic for b in self.bodies])
        self.R0 = np.array(self.R0)
        self.p = np.array(self.p)
        self.z = np.eye(3)[self.axis]

    # ----------------------------------------------------------------------------------------
    def _rot(self, k, q):
        """(N,3,3) rotation of joint frame k relative to its parent: R0_k @ Rot(axis_k, q)."""
        c, s = np.cos(q), np.sin(q)
        n = q.shape[0]
        R = np.zeros((n, 3, 3))
        a = self.axis[k]
        i, j = [(1, 2), (2, 0), (0, 1)][a]
        R[:, a, a] = 1.0
        R[:, i, i] = c
        R[:, j, j] = c
        R[:, i, j] = -s
        R[:, j, i] = s
        return np.einsum("ab,nbc->nac", self.R0[k], R)

    def rnea(self, q, qd, qdd, gravity=G):
        """Joint torques (N,7) for q, qd, qdd of shape (N,7); fixed base, gravity along -z."""
        q, qd, qdd = (np.asarray(x, float) for x in (q, qd, qdd))
        n = q.shape[0]
        w = np.zeros((n, 3))
        wd = np.zeros((n, 3))
        a = np.zeros((n, 3))
        a[:, 2] = gravity  # base acceleration = -g (gravity trick)
        Rs, F, Nm = [], [], []
        for k in range(7):
            R = self._rot(k, q[:, k])
            Rs.append(R)
            Rt = np.swapaxes(R, 1, 2)
            pk = self.p[k]
            a = a + np.cross(wd, pk) + np.cross(w, np.cross(w, pk))
            a = np.einsum("nab,nb->na", Rt, a)
            wp = np.einsum("nab,nb->na", Rt, w)
            z = self.z[k]
            w = wp + qd[:, k:k + 1] * z
            wd = np.einsum("nab,nb->na", Rt, wd) + qdd[:, k:k + 1] * z + np.cross(wp, z) * qd[:, k:k + 1]
            ck = self.c[k]
            ac = a + np.cross(wd, ck) + np.cross(w, np.cross(w, ck))
            F.append(self.m[k] * ac)
            Iw = w @ self.Ic[k].T
            Nm.append(wd @ self.Ic[k].T + np.cross(w, Iw))
        tau = np.zeros((n, 7))
        f = np.zeros((n, 3))
        nn = np.zeros((n, 3))
        for k in range(6, -1, -1):
            if k < 6:
                Rn = Rs[k + 1]
                fc = np.einsum("nab,nb->na", Rn, f)
                nc = np.einsum("nab,nb->na", Rn, nn)
                nn = Nm[k] + nc + np.cross(self.c[k], F[k]) + np.cross(self.p[k + 1], fc)
                f = F[k] + fc
            else:
                f = F[k]
                nn = Nm[k] + np.cross(self.c[k], F[k])
            tau[:, k] = nn @ self.z[k]
        return tau

    def fk_bodies(self, q):
        """World rotation (N,7,3,3) and origin position (N,7,3) of each body frame (torso at 0)."""
        q = np.asarray(q, float)
        n = q.shape[0]
        R = np.broadcast_to(np.eye(3), (n, 3, 3))
        p = np.zeros((n, 3))
        Rw, pw = [], []
        for k in range(7):
            p = p + np.einsum("nab,b->na", R, self.p[k])
            R = R @ self._rot(k, q[:, k])
            Rw.append(R)
            pw.append(p)
        return np.stack(Rw, 1), np.stack(pw, 1)

    def potential(self, q, gravity=G):
        Rw, pw = self.fk_bodies(q)
        com = pw + np.einsum("nkab,kb->nka", Rw, self.c)
        return gravity * (com[..., 2] * self.m).sum(1)

    def kinetic(self, q, qd):
        """Kinetic energy via body velocities (independent of the RNEA recursion)."""
        q, qd = np.asarray(q, float), np.asarray(qd, float)
        Rw, pw = self.fk_bodies(q)
        n = q.shape[0]
        com = pw + np.einsum("nkab,kb->nka", Rw, self.c)
        T = np.zeros(n)
        # world angular velocity and COM velocity via the geometric Jacobian
        axes_w = np.einsum("nkab,kb->nka", Rw, self.z)
        for k in range(7):
            wk = np.zeros((n, 3))
            vk = np.zeros((n, 3))
            for j in range(k + 1):
                wk += axes_w[:, j] * qd[:, j:j + 1]
                vk += np.cross(axes_w[:, j], com[:, k] - pw[:, j]) * qd[:, j:j + 1]
            wb = np.einsum("nba,nb->na", Rw[:, k], wk)
            T += 0.5 * self.m[k] * (vk * vk).sum(1) + 0.5 * np.einsum("na,ab,nb->n", wb, self.Ic[k], wb)
        return T
