// A sphere on a heightfield's surface: jaxenvs' collider for MuJoCo's C engine.
//
// MuJoCo C collides a geom with a heightfield as with a set of triangular prisms (each
// cell's two triangles extruded down to the base) by convex penetration; near a prism's
// side the shortest way out of it is sideways, so a sphere pressed a few millimetres into
// FLAT ground gets contact normals tilted by up to 60 degrees (benchmarks/hfield_normals.py).
// This collider treats the heightfield as the surface it draws, MuJoCo's own triangles
// (each cell split along the diagonal from sample (r, c) to (r + 1, c + 1)), and gives one
// contact per local minimum of the distance from the sphere's centre to that surface:
//   * for each triangle within reach, the closest point q to the centre p; its normal is
//     the face's where q lies inside the triangle (also with p below the face: a deep
//     press), (p - q) / |p - q| where q is on an edge or corner with p above the face;
//   * a triangle's point is dropped where a triangle that holds it has a strictly closer
//     point (not a local minimum: on flat ground an edge's tilted point is never kept),
//     and points that coincide are kept once;
//   * the deepest kMaxContacts are kept: on flat ground one contact with a vertical
//     normal, against a riser's foot one on the tread and one on the riser.
// dist is |p - q| - radius (the face's signed distance - radius for a face point), the
// position halfway between the two surfaces, the normal from the heightfield to the
// sphere, the tangent left to MuJoCo (zero).
//
// It is installed in MuJoCo's collision table (mjCOLLISIONFUNC, public) for heightfield
// and sphere, and used only for models that ask for it with the numeric kSurfaceNumeric
// (value 1; jaxenvs.scenes.Scene adds it); every other model gets MuJoCo's own collider,
// called as before. MJX has its own heightfield collider and ignores the numeric.

#include <mujoco/mujoco.h>

#include <algorithm>
#include <cmath>
#include <mutex>

namespace {

constexpr char kSurfaceNumeric[] = "jaxenvs_hfield_surface";
constexpr int kMaxCandidates = 64;  // triangles within a foot's reach: 8 on 2.5 cm cells
constexpr int kMaxContacts = 4;
constexpr mjtNum kSame = 1e-9;      // m: points this close are one point

mjfCollision stock = nullptr;  // MuJoCo's heightfield-sphere collider, for other models
std::once_flag installed;

struct Candidate {
  mjtNum dist;       // |p - q| - radius (signed for a face point)
  mjtNum q[3];       // the closest point of the triangle, hfield frame
  mjtNum normal[3];  // hfield frame, from the surface to the sphere
  int tri;           // the triangle: 2 * (r * ncol + c) + (0 lower, 1 upper)
};

inline void Sub(mjtNum* out, const mjtNum* a, const mjtNum* b) {
  out[0] = a[0] - b[0], out[1] = a[1] - b[1], out[2] = a[2] - b[2];
}
inline mjtNum Dot(const mjtNum* a, const mjtNum* b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

// The point of triangle (a, b, c) closest to p (Ericson, Real-Time Collision Detection
// 5.1.5); true where it lies inside the face (not on an edge or a corner).
bool Closest(const mjtNum* p, const mjtNum* a, const mjtNum* b, const mjtNum* c, mjtNum* q) {
  mjtNum ab[3], ac[3], ap[3], bp[3], cp[3];
  Sub(ab, b, a), Sub(ac, c, a), Sub(ap, p, a);
  mjtNum d1 = Dot(ab, ap), d2 = Dot(ac, ap);
  auto at = [q](const mjtNum* x) { q[0] = x[0], q[1] = x[1], q[2] = x[2]; };
  auto along = [q](const mjtNum* x, const mjtNum* dir, mjtNum t) {
    for (int i = 0; i < 3; ++i) q[i] = x[i] + t * dir[i];
  };
  if (d1 <= 0 && d2 <= 0) return at(a), false;
  Sub(bp, p, b);
  mjtNum d3 = Dot(ab, bp), d4 = Dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return at(b), false;
  mjtNum vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return along(a, ab, d1 / (d1 - d3)), false;
  Sub(cp, p, c);
  mjtNum d5 = Dot(ab, cp), d6 = Dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return at(c), false;
  mjtNum vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return along(a, ac, d2 / (d2 - d6)), false;
  mjtNum va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    mjtNum bc[3];
    Sub(bc, c, b);
    return along(b, bc, (d4 - d3) / ((d4 - d3) + (d5 - d6))), false;
  }
  mjtNum denom = 1 / (va + vb + vc);
  mjtNum v = vb * denom, w = vc * denom;
  for (int i = 0; i < 3; ++i) q[i] = a[i] + ab[i] * v + ac[i] * w;
  return true;
}

// True if point x lies on triangle (a, b, c) (within kSame).
bool Holds(const mjtNum* x, const mjtNum* a, const mjtNum* b, const mjtNum* c) {
  mjtNum q[3], d[3];
  Closest(x, a, b, c, q);
  Sub(d, x, q);
  return Dot(d, d) < kSame * kSame;
}

bool Wants(const mjModel* m) {
  int id = mj_name2id(m, mjOBJ_NUMERIC, kSurfaceNumeric);
  return id >= 0 && m->numeric_size[id] > 0 && m->numeric_data[m->numeric_adr[id]] != 0;
}

int SurfaceSphere(const mjModel* m, mjData* d, mjPreContact* con, int g1, int g2,
                  mjtNum margin) {
  if (!Wants(m)) return stock(m, d, con, g1, g2, margin);
  const mjtNum* pos1 = d->geom_xpos + 3 * g1;
  const mjtNum* mat1 = d->geom_xmat + 9 * g1;
  const mjtNum radius = m->geom_size[3 * g2];
  int hid = m->geom_dataid[g1];
  int nrow = m->hfield_nrow[hid], ncol = m->hfield_ncol[hid];
  const mjtNum* size = m->hfield_size + 4 * hid;
  const float* data = m->hfield_data + m->hfield_adr[hid];

  // the sphere's centre in the heightfield's frame
  mjtNum rel[3], p[3];
  Sub(rel, d->geom_xpos + 3 * g2, pos1);
  mju_mulMatTVec3(p, mat1, rel);
  mjtNum reach = radius + margin;
  if (p[0] - reach > size[0] || p[0] + reach < -size[0] || p[1] - reach > size[1] ||
      p[1] + reach < -size[1] || p[2] - reach > size[2] || p[2] + reach < -size[3]) {
    return 0;
  }
  mjtNum dx = 2 * size[0] / (ncol - 1), dy = 2 * size[1] / (nrow - 1);
  int c0 = std::max(0, static_cast<int>(std::floor((p[0] - reach + size[0]) / dx)));
  int c1 = std::min(ncol - 1, static_cast<int>(std::ceil((p[0] + reach + size[0]) / dx)));
  int r0 = std::max(0, static_cast<int>(std::floor((p[1] - reach + size[1]) / dy)));
  int r1 = std::min(nrow - 1, static_cast<int>(std::ceil((p[1] + reach + size[1]) / dy)));

  auto vertex = [&](int r, int c, mjtNum* v) {
    v[0] = dx * c - size[0], v[1] = dy * r - size[1];
    v[2] = data[r * ncol + c] * size[2];
  };
  auto corners = [&](int tri, mjtNum* a, mjtNum* b, mjtNum* c) {
    int cell = tri / 2, r = cell / ncol, col = cell % ncol;
    vertex(r, col, a);
    vertex(r + 1, col + 1, c);
    if (tri % 2 == 0) vertex(r, col + 1, b);  // lower: (r, c), (r, c+1), (r+1, c+1)
    else vertex(r + 1, col, b);               // upper: (r, c), (r+1, c), (r+1, c+1)
  };

  Candidate cand[kMaxCandidates];
  int n = 0;
  for (int r = r0; r < r1 && n < kMaxCandidates; ++r) {
    for (int c = c0; c < c1 && n < kMaxCandidates; ++c) {
      for (int up = 0; up < 2 && n < kMaxCandidates; ++up) {
        int tri = 2 * (r * ncol + c) + up;
        mjtNum a[3], b[3], cc[3], q[3], e1[3], e2[3], face[3], pq[3];
        corners(tri, a, b, cc);
        if (std::max({a[2], b[2], cc[2]}) < p[2] - reach) continue;
        bool inside = Closest(p, a, b, cc, q);
        Sub(e1, b, a), Sub(e2, cc, a);
        mju_cross(face, e1, e2);
        mju_normalize3(face);
        if (face[2] < 0) mju_scl3(face, face, -1);
        Sub(pq, p, q);
        Candidate& k = cand[n];
        if (inside) {
          k.dist = Dot(pq, face) - radius;
          mju_copy3(k.normal, face);
        } else {
          mjtNum len = mju_norm3(pq);
          if (Dot(pq, face) <= 0 || len < mjMINVAL) continue;  // below: another face's
          k.dist = len - radius;
          mju_scl3(k.normal, pq, 1 / len);
        }
        if (k.dist >= margin) continue;
        mju_copy3(k.q, q);
        k.tri = tri;
        ++n;
      }
    }
  }

  // keep the local minima, deepest first, each point once
  std::sort(cand, cand + n, [](const Candidate& x, const Candidate& y) {
    return x.dist < y.dist || (x.dist == y.dist && x.tri < y.tri);
  });
  int kept[kMaxContacts];
  int nkept = 0;
  for (int i = 0; i < n && nkept < kMaxContacts; ++i) {
    bool keep = true;
    for (int j = 0; j < i && keep; ++j) {
      mjtNum a[3], b[3], cc[3], gap[3];
      Sub(gap, cand[i].q, cand[j].q);
      bool same = Dot(gap, gap) < kSame * kSame;
      if (cand[j].dist < cand[i].dist - kSame) {
        corners(cand[j].tri, a, b, cc);
        keep = !Holds(cand[i].q, a, b, cc);  // a closer point on a triangle holding q
      } else if (same) {
        keep = false;  // the same point, from a neighbour
      }
    }
    if (keep) kept[nkept++] = i;
  }

  for (int k = 0; k < nkept; ++k) {
    const Candidate& c = cand[kept[k]];
    mjtNum mid[3];
    for (int i = 0; i < 3; ++i) mid[i] = c.q[i] + c.normal[i] * (c.dist / 2);
    mju_mulMatVec3(con[k].normal, mat1, c.normal);
    mju_mulMatVec3(con[k].pos, mat1, mid);
    mju_addTo3(con[k].pos, pos1);
    con[k].dist = c.dist;
    mju_zero3(con[k].tangent);
  }
  return nkept;
}

}  // namespace

// the only exported symbol (the library is built with hidden visibility)
#pragma GCC visibility push(default)
extern "C" {

// Install the surface collider for heightfield-sphere pairs (once per process; MuJoCo's
// own is kept for every model without the numeric). Returns the numeric's name.
const char* jaxenvs_install_hfield_surface() {
  std::call_once(installed, [] {
    stock = mjCOLLISIONFUNC[mjGEOM_HFIELD][mjGEOM_SPHERE];
    mjCOLLISIONFUNC[mjGEOM_HFIELD][mjGEOM_SPHERE] = SurfaceSphere;
  });
  return kSurfaceNumeric;
}

}  // extern "C"

#pragma GCC visibility pop
