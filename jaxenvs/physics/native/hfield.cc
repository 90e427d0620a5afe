// A sphere on a heightfield's surface: jaxenvs' collider for MuJoCo's C engine.
//
// MuJoCo C collides a geom with a heightfield as with a set of triangular prisms (each
// cell's two triangles extruded down to the base) by convex penetration; near a prism's
// side the shortest way out of it is sideways, so a sphere pressed a few millimetres into
// FLAT ground gets contact normals tilted by up to 60 degrees (benchmarks/hfield_normals.py).
// This collider treats the heightfield as the surface it draws, MuJoCo's own triangles
// (each cell split along the diagonal from sample (r, c) to (r + 1, c + 1)):
//   * with the sphere's centre p above the surface at its own (x, y) (or off the field):
//     for each triangle within reach, its closest point q; a contact for each local
//     minimum of |p - q| over the surface (a point is dropped where any triangle holding
//     it has a strictly closer point, so on flat ground no neighbour's tilted edge point
//     is kept, and a point reached from behind its face never is), with the normal
//     (p - q) / |p - q| (the face's, inside a face) and dist |p - q| - radius; points that
//     coincide are kept once, the deepest kMaxContacts in all;
//   * with p below the surface at its own (x, y) (pressed deeper than its radius): one
//     contact on the triangle under p, its face's normal, dist the signed distance from
//     the face's plane - radius, so a deep press is pushed back up, never through.
// On flat ground that is one vertical contact as deep as the sphere is pressed; in a
// crease (a riser's foot) one contact on each face the sphere reaches that is a local
// minimum. The position is halfway between the two surfaces, the normal from the
// heightfield to the sphere, the tangent left to MuJoCo (zero).
//
// It is installed in MuJoCo's collision table (mjCOLLISIONFUNC, public) for heightfield
// and sphere, and used only for models that ask for it with the numeric kSurfaceNumeric
// (value 1; jaxenvs.scenes.Scene adds it); every other model gets MuJoCo's own collider,
// called as before. MJX has its own heightfield collider and ignores the numeric.

#include <mujoco/mujoco.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <mutex>
#include <vector>

namespace {

constexpr char kSurfaceNumeric[] = "jaxenvs_hfield_surface";
constexpr int kOnStack = 64;    // triangles within reach kept on the stack (a foot: 8)
constexpr int kMaxContacts = 4;
constexpr mjtNum kSame = 1e-9;  // m: points and distances this close are the same

// MuJoCo's heightfield-sphere collider, for other models: stored before the table entry is
// replaced, so a thread that calls the new entry sees it
std::atomic<mjfCollision> stock{nullptr};
std::once_flag installed;

struct Tri {
  mjtNum dist;       // |p - q|
  mjtNum q[3];       // the triangle's point closest to p, hfield frame
  mjtNum normal[3];  // hfield frame, from the surface to the sphere
  int id;            // 2 * (r * ncol + c) + (0 lower, 1 upper)
  bool candidate;    // p in front of its face (a contact unless a closer point blocks it)
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

// The upward unit normal of triangle (a, b, c).
void FaceNormal(const mjtNum* a, const mjtNum* b, const mjtNum* c, mjtNum* n) {
  mjtNum e1[3], e2[3];
  Sub(e1, b, a), Sub(e2, c, a);
  mju_cross(n, e1, e2);
  mju_normalize3(n);
  if (n[2] < 0) mju_scl3(n, n, -1);
}

bool Wants(const mjModel* m) {
  int id = mj_name2id(m, mjOBJ_NUMERIC, kSurfaceNumeric);
  return id >= 0 && m->numeric_size[id] > 0 && m->numeric_data[m->numeric_adr[id]] != 0;
}

// The heightfield of a model: its size, samples and the corners of its triangles.
struct Field {
  const mjtNum* size;
  const float* data;
  int nrow, ncol;
  mjtNum dx, dy;

  void Vertex(int r, int c, mjtNum* v) const {
    v[0] = dx * c - size[0], v[1] = dy * r - size[1];
    v[2] = data[r * ncol + c] * size[2];
  }
  void Corners(int id, mjtNum* a, mjtNum* b, mjtNum* c) const {
    int cell = id / 2, r = cell / ncol, col = cell % ncol;
    Vertex(r, col, a);
    Vertex(r + 1, col + 1, c);
    if (id % 2 == 0) Vertex(r, col + 1, b);  // lower: (r, c), (r, c+1), (r+1, c+1)
    else Vertex(r + 1, col, b);               // upper: (r, c), (r+1, c), (r+1, c+1)
  }
  // The triangle under (x, y) and whether (x, y) is over the field at all.
  bool Under(const mjtNum* p, int* id) const {
    mjtNum u = (p[0] + size[0]) / dx, v = (p[1] + size[1]) / dy;
    if (u < 0 || v < 0 || u > ncol - 1 || v > nrow - 1) return false;
    int c = std::min(static_cast<int>(u), ncol - 2), r = std::min(static_cast<int>(v), nrow - 2);
    *id = 2 * (r * ncol + c) + ((u - c) >= (v - r) ? 0 : 1);
    return true;
  }
};

// Writes contact k: surface point q, normal n (hfield frame), distance dist.
void Emit(mjPreContact* con, const mjtNum* pos1, const mjtNum* mat1, const mjtNum* q,
          const mjtNum* n, mjtNum dist) {
  mjtNum mid[3];
  for (int i = 0; i < 3; ++i) mid[i] = q[i] + n[i] * (dist / 2);
  mju_mulMatVec3(con->normal, mat1, n);
  mju_mulMatVec3(con->pos, mat1, mid);
  mju_addTo3(con->pos, pos1);
  con->dist = dist;
  mju_zero3(con->tangent);
}

int SurfaceSphere(const mjModel* m, mjData* d, mjPreContact* con, int g1, int g2,
                  mjtNum margin) {
  if (!Wants(m)) return stock.load(std::memory_order_acquire)(m, d, con, g1, g2, margin);
  const mjtNum* pos1 = d->geom_xpos + 3 * g1;
  const mjtNum* mat1 = d->geom_xmat + 9 * g1;
  const mjtNum radius = m->geom_size[3 * g2];
  int hid = m->geom_dataid[g1];
  Field f{m->hfield_size + 4 * hid, m->hfield_data + m->hfield_adr[hid], m->hfield_nrow[hid],
          m->hfield_ncol[hid], 0, 0};
  f.dx = 2 * f.size[0] / (f.ncol - 1), f.dy = 2 * f.size[1] / (f.nrow - 1);

  // the sphere's centre in the heightfield's frame
  mjtNum rel[3], p[3];
  Sub(rel, d->geom_xpos + 3 * g2, pos1);
  mju_mulMatTVec3(p, mat1, rel);
  mjtNum reach = radius + margin;
  const mjtNum* size = f.size;
  if (p[0] - reach > size[0] || p[0] + reach < -size[0] || p[1] - reach > size[1] ||
      p[1] + reach < -size[1] || p[2] - reach > size[2] || p[2] + reach < -size[3]) {
    return 0;
  }

  // pressed below the surface at its own (x, y): the face under it pushes it back up
  int under;
  if (f.Under(p, &under)) {
    mjtNum a[3], b[3], c[3], n[3], ap[3];
    f.Corners(under, a, b, c);
    FaceNormal(a, b, c, n);
    Sub(ap, p, a);
    mjtNum s = Dot(ap, n);  // along the face normal: below the surface iff below the face
    if (s <= 0) {
      mjtNum q[3];
      Closest(p, a, b, c, q);  // on the face: p's projection onto it where that is inside
      if (s - radius >= margin) return 0;
      Emit(con, pos1, mat1, q, n, s - radius);
      return 1;
    }
  }

  // above it: every triangle within reach
  int c0 = std::max(0, static_cast<int>(std::floor((p[0] - reach + size[0]) / f.dx)));
  int c1 = std::min(f.ncol - 1, static_cast<int>(std::ceil((p[0] + reach + size[0]) / f.dx)));
  int r0 = std::max(0, static_cast<int>(std::floor((p[1] - reach + size[1]) / f.dy)));
  int r1 = std::min(f.nrow - 1, static_cast<int>(std::ceil((p[1] + reach + size[1]) / f.dy)));
  int count = std::max(0, (r1 - r0) * (c1 - c0) * 2);
  Tri local[kOnStack];
  std::vector<Tri> heap;  // a sphere over more than kOnStack triangles (not a foot)
  if (count > kOnStack) heap.resize(count);
  Tri* tri = count > kOnStack ? heap.data() : local;
  // a triangle out of reach is neither a contact nor closer than one: not kept
  int n = 0;
  for (int r = r0; r < r1; ++r) {
    for (int col = c0; col < c1; ++col) {
      for (int up = 0; up < 2; ++up) {
        Tri& t = tri[n];
        mjtNum a[3], b[3], c[3], face[3], pq[3];
        t.id = 2 * (r * f.ncol + col) + up;
        f.Corners(t.id, a, b, c);
        if (std::max({a[2], b[2], c[2]}) <= p[2] - reach) continue;
        bool inside = Closest(p, a, b, c, t.q);
        Sub(pq, p, t.q);
        t.dist = mju_norm3(pq);
        if (t.dist >= reach) continue;
        ++n;
        // a point reached from behind its face is never a contact (a closer one is)
        FaceNormal(a, b, c, face);
        t.candidate = Dot(pq, face) > 0;
        if (!t.candidate) continue;
        if (inside || t.dist < mjMINVAL) mju_copy3(t.normal, face);
        else mju_scl3(t.normal, pq, 1 / t.dist);
      }
    }
  }

  // the local minima, deepest first, each point once
  int order[kMaxContacts + 1];
  int found = 0;
  for (;;) {
    int best = -1;
    for (int i = 0; i < n; ++i) {
      if (!tri[i].candidate) continue;
      if (best < 0 || tri[i].dist < tri[best].dist ||
          (tri[i].dist == tri[best].dist && tri[i].id < tri[best].id)) {
        best = i;
      }
    }
    if (best < 0 || found == kMaxContacts) break;
    Tri& t = tri[best];
    t.candidate = false;
    bool keep = true;
    for (int j = 0; j < n && keep; ++j) {  // a strictly closer point on a triangle holding q
      if (j == best || !(tri[j].dist < t.dist - kSame)) continue;
      mjtNum a[3], b[3], c[3];
      f.Corners(tri[j].id, a, b, c);
      keep = !Holds(t.q, a, b, c);
    }
    for (int k = 0; k < found && keep; ++k) {  // the same point, from a neighbour
      mjtNum gap[3];
      Sub(gap, t.q, tri[order[k]].q);
      keep = Dot(gap, gap) >= kSame * kSame;
    }
    if (keep) order[found++] = best;
  }
  for (int k = 0; k < found; ++k) {
    const Tri& t = tri[order[k]];
    Emit(con + k, pos1, mat1, t.q, t.normal, t.dist - radius);
  }
  return found;
}

}  // namespace

// the only exported symbol (the library is built with hidden visibility)
#pragma GCC visibility push(default)
extern "C" {

// Install the surface collider for heightfield-sphere pairs (once per process; MuJoCo's
// own is kept for every model without the numeric). Returns the numeric's name.
const char* jaxenvs_install_hfield_surface() {
  std::call_once(installed, [] {
    stock.store(mjCOLLISIONFUNC[mjGEOM_HFIELD][mjGEOM_SPHERE], std::memory_order_release);
    mjCOLLISIONFUNC[mjGEOM_HFIELD][mjGEOM_SPHERE] = SurfaceSphere;
  });
  return kSurfaceNumeric;
}

}  // extern "C"

#pragma GCC visibility pop
