#include "dynamic_occupancy_grid/core/layers/layers.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>

#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/common/parallel.h"

// The vector loop of layerOccupancy: AVX2 + FMA, chosen at run time (the build stays
// generic x86-64); elsewhere every cell takes the reference's way.
#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define DOG_LAYERS_AVX2 1
#else
#define DOG_LAYERS_AVX2 0
#endif

namespace dynamic_occupancy_grid {
namespace core {
namespace {

float cellValue(const CellGrid::Tile& tile, int i, Layer layer, std::int64_t step,
                std::int64_t horizon_steps) {
  const TransitionParams params{tile.p_occ_given_free[i], tile.p_free_given_occ[i]};
  switch (layer) {
    case Layer::kBelief:
      return static_cast<float>(predictOccupancy(tile.p_occ[i], params, step - tile.last_step[i]));
    case Layer::kPredicted:
      return static_cast<float>(
          predictOccupancy(tile.p_occ[i], params, step + horizon_steps - tile.last_step[i]));
    case Layer::kStationary: {
      const std::optional<double> pi_occ = stationaryOccupancy(params);
      return pi_occ ? static_cast<float>(*pi_occ) : tile.p_occ[i];
    }
    case Layer::kOccGivenFree:
      return tile.p_occ_given_free[i];
    case Layer::kFreeGivenOcc:
      return tile.p_free_given_occ[i];
    case Layer::kStatic:
      return static_cast<float>(logOddsToProbability(tile.log_odds[i]));
  }
  return std::numeric_limits<float>::quiet_NaN();
}

}  // namespace

std::string layerName(Layer layer) {
  switch (layer) {
    case Layer::kBelief:
      return "belief";
    case Layer::kPredicted:
      return "predicted";
    case Layer::kStationary:
      return "stationary";
    case Layer::kOccGivenFree:
      return "p_occ_given_free";
    case Layer::kFreeGivenOcc:
      return "p_free_given_occ";
    case Layer::kStatic:
      return "static_map";
  }
  return "unknown";
}

void evaluateLayer(const CellGrid& grid, Layer layer, std::int64_t step,
                   std::int64_t horizon_steps, const CellBox& box, std::vector<float>* values) {
  constexpr float kUnknown = std::numeric_limits<float>::quiet_NaN();
  values->assign(static_cast<std::size_t>(box.width() * box.height()), kUnknown);
  if (box.empty()) return;
  const std::int64_t width = box.width();
  for (std::int32_t y = box.min_y; y <= box.max_y; ++y) {
    float* row = values->data() + static_cast<std::size_t>((std::int64_t{y} - box.min_y) * width);
    // One tile lookup per run of cells sharing a tile.
    for (std::int32_t x = box.min_x; x <= box.max_x;) {
      const std::int32_t run_end =
          std::min<std::int32_t>(box.max_x, (x | (CellGrid::kTileSize - 1)));
      if (const CellGrid::Tile* tile = grid.findTile(x, y)) {
        for (std::int32_t cx = x; cx <= run_end; ++cx) {
          const int i = CellGrid::offsetOf(cx, y);
          if (tile->last_step[i] == kNeverObserved) continue;
          row[cx - box.min_x] = cellValue(*tile, i, layer, step, horizon_steps);
        }
      }
      if (run_end == std::numeric_limits<std::int32_t>::max()) break;
      x = run_end + 1;
    }
  }
}

std::int8_t occupancyValue(float value, float full_scale) {
  const float scale = 100.0f / full_scale;
  return std::isnan(value) ? std::int8_t{-1}
                           : static_cast<std::int8_t>(std::lround(std::clamp(value * scale, 0.0f, 100.0f)));
}

void toOccupancyValues(const std::vector<float>& values, float full_scale,
                       std::vector<std::int8_t>* occupancy) {
  occupancy->resize(values.size());
  for (std::size_t i = 0; i < values.size(); ++i) (*occupancy)[i] = occupancyValue(values[i], full_scale);
}

void OccupancyThresholds::validate() const {
  if (!(std::isfinite(free_thresh) && std::isfinite(occupied_thresh) && free_thresh >= 0.0 &&
        free_thresh < occupied_thresh && occupied_thresh <= 1.0)) {
    throw std::invalid_argument("occupancy thresholds need 0 <= free_thresh < occupied_thresh <= 1, got free_thresh " +
                                std::to_string(free_thresh) + ", occupied_thresh " + std::to_string(occupied_thresh));
  }
}

std::int8_t thresholdedOccupancyValue(float value, const OccupancyThresholds& thresholds) {
  if (thresholds.mode == ThresholdMode::kRaw) return occupancyValue(value, 1.0f);
  const double span = thresholds.occupied_thresh - thresholds.free_thresh;
  const double p = value;
  std::int8_t result = -1;
  if (std::isnan(p)) {
    result = -1;
  } else if (p > thresholds.occupied_thresh) {
    result = 100;
  } else if (p < thresholds.free_thresh) {
    result = 0;
  } else if (thresholds.mode == ThresholdMode::kScale) {
    // map_server's image_loader: value = 1 + 98 * ratio, assigned to an int (truncated).
    result = static_cast<std::int8_t>(1.0 + 98.0 * (p - thresholds.free_thresh) / span);
  }
  return result;
}

void toThresholdedOccupancyValues(const std::vector<float>& values, const OccupancyThresholds& thresholds,
                                  std::vector<std::int8_t>* occupancy) {
  occupancy->resize(values.size());
  for (std::size_t i = 0; i < values.size(); ++i) (*occupancy)[i] = thresholdedOccupancyValue(values[i], thresholds);
}

// =====================================================================================
// layerOccupancy: layer values straight to OccupancyGrid values.
//
// The reference is evaluateLayer + toOccupancyValues / toThresholdedOccupancyValues: a float
// v per cell (the layer's double rounded to float), then a function g(v) -> -1..100. The
// fast path never computes v the reference's way; it proves g(v) instead:
//
// 1. g is piecewise constant in v, every output on one interval of floats (the scalings are
//    monotone, or three monotone pieces for the thresholds). The pieces are found once per
//    scaling by bisection over the floats in order, with g itself. A float boundary F
//    (predecessor P) is a boundary D in the doubles: the smallest double that rounds to F or
//    above (the midpoint of P and F, or the next double when the midpoint rounds to P).
//    So g(float(x)) is a step function of the layer's double x with exact thresholds D.
// 2. Probability layers: x and an upper bound m of |x - x_reference| (m = 0 where the
//    computation is the reference's to the bit: stored floats, pi = p_of / (p_of + p_fo);
//    for the prediction lambda^gap by repeated squaring instead of pow, with the error
//    bound derived below). A cell whose [x - m, x + m] lies inside one interval is decided;
//    the interior pieces of the 0..100 scalings are consecutive integers on nearly equally
//    spaced thresholds, so the interval is found as floor(c x + c0), with the largest
//    deviation of the real thresholds from that line (measured, ~1e-6) as a guard band.
// 3. static_map: g(float(logistic(log_odds))) is a function of the stored float log_odds,
//    again piecewise constant; a table over the top 20 bits of the float's pattern (4096
//    consecutive floats per entry) holds the output of every entry whose floats all lie in
//    one piece, and "resolve" for the few that hold a boundary (or NaN).
// Cells not decided (inputs outside [0, 1], near a threshold, NaN, table entries with a
// boundary) are computed the reference's way. Never-observed cells are -1.
// =====================================================================================

namespace {

constexpr std::int8_t kResolve = std::numeric_limits<std::int8_t>::min();  // not an output of g

// Floats in order: key(a) < key(b) iff a < b, for non-NaN floats other than -0 / +0 (whose
// keys are adjacent). Keys from key(-inf) to key(+inf) cover exactly the non-NaN floats.
std::uint32_t bitsOf(float f) {
  std::uint32_t b;
  std::memcpy(&b, &f, sizeof b);
  return b;
}
float floatOfBits(std::uint32_t b) {
  float f;
  std::memcpy(&f, &b, sizeof f);
  return f;
}
std::uint32_t keyOfBits(std::uint32_t bits) { return (bits & 0x80000000u) != 0 ? ~bits : (bits | 0x80000000u); }
std::uint32_t bitsOfKey(std::uint32_t key) { return (key & 0x80000000u) != 0 ? (key & 0x7FFFFFFFu) : ~key; }
float floatOfKey(std::uint32_t key) { return floatOfBits(bitsOfKey(key)); }
constexpr std::uint32_t kKeyMinusInf = 0x007FFFFFu;
constexpr std::uint32_t kKeyPlusInf = 0xFF800000u;

/// One piece of a piecewise constant function of a float: `value` from the float of
/// first_key up to the next piece.
struct Piece {
  std::uint32_t first_key;
  std::int8_t value;
};
using FloatFunction = std::function<std::int8_t(float)>;

void splitPieces(const FloatFunction& f, std::uint32_t lo, std::uint32_t hi, std::int8_t f_lo, std::int8_t f_hi,
                 std::vector<Piece>* pieces) {
  if (f_lo == f_hi) return;  // one output on [lo, hi]: its floats are one interval
  if (hi - lo == 1) {
    pieces->push_back(Piece{hi, f_hi});
    return;
  }
  const std::uint32_t mid = lo + ((hi - lo) / 2);
  const std::int8_t f_mid = f(floatOfKey(mid));
  splitPieces(f, lo, mid, f_lo, f_mid, pieces);
  splitPieces(f, mid, hi, f_mid, f_hi, pieces);
}

/// The pieces of f over [-inf, +inf], in order, for an f that takes every output on one
/// interval of floats (checked by the tests for the scalings here).
std::vector<Piece> findPieces(const FloatFunction& f) {
  const std::int8_t first = f(-std::numeric_limits<float>::infinity());
  const std::int8_t last = f(std::numeric_limits<float>::infinity());
  std::vector<Piece> pieces{Piece{kKeyMinusInf, first}};
  splitPieces(f, kKeyMinusInf, kKeyPlusInf, first, last, &pieces);
  return pieces;
}

/// The smallest double that rounds (to nearest, ties to even) to the float of `key` or
/// above; nullopt where that is not a midpoint of two finite floats of different values.
std::optional<double> doubleBoundary(std::uint32_t key) {
  const float f = floatOfKey(key);
  const float p = floatOfKey(key - 1);
  if (!std::isfinite(f) || !std::isfinite(p) || !(p < f)) return std::nullopt;
  const double mid = (static_cast<double>(p) + static_cast<double>(f)) / 2.0;  // exact
  // At the midpoint itself the even float wins (the significand's lowest bit).
  return (bitsOfKey(key) & 1u) == 0 ? mid : std::nextafter(mid, std::numeric_limits<double>::infinity());
}

/// g(float(x)) as a function of a double x, in the form the vector loop decides:
///   x < lo: below;  x >= hi: above;  lo <= x < hi: `mid`, or (linear) the integer
///   floor(c x + c0) in [kmin, kmax], which equals the output wherever c x + c0 is at least
///   eps0 away from an integer.
/// all_linear (the 0..100 scalings: every output from the lowest to the highest in order):
///   the output is floor(y) for y = c x + c0 clamped to [kmin + 0.5, kmax + 0.5], wherever y
///   is at least eps0 away from an integer (lo, hi, below, above, mid unused).
struct DoubleClassifier {
  bool usable = false;
  bool all_linear = false;
  double lo = std::numeric_limits<double>::infinity();
  double hi = std::numeric_limits<double>::infinity();
  std::int8_t below = -1;
  std::int8_t above = -1;
  std::int8_t mid = -1;
  bool linear = false;
  double c = 0.0;
  double c0 = 0.0;
  double eps0 = 0.0;
  double kmin = 0.0;
  double kmax = 0.0;
};

DoubleClassifier makeDoubleClassifier(const std::vector<Piece>& pieces) {
  DoubleClassifier k;
  const std::size_t n = pieces.size();
  k.below = pieces[0].value;
  if (n == 1) {
    k.usable = true;  // lo = hi = +inf: every x is below
    return k;
  }
  std::vector<double> d(n, 0.0);
  for (std::size_t i = 1; i < n; ++i) {
    const std::optional<double> boundary = doubleBoundary(pieces[i].first_key);
    if (!boundary) return k;
    d[i] = *boundary;
  }
  k.lo = d[1];
  k.hi = d[n - 1];
  k.above = pieces[n - 1].value;
  // Rounding of c x + c0 (in the fit and in the loop, FMA or not) where it decides: a few
  // ulps of its terms.
  const auto rounding = [](double c0, double kmax) {
    return 16.0 * std::numeric_limits<double>::epsilon() * (2.0 * (std::abs(c0) + kmax + 2.0));
  };
  bool consecutive = n >= 3 && pieces[0].value >= 0;
  for (std::size_t i = 1; consecutive && i < n; ++i) consecutive = pieces[i].value == pieces[0].value + static_cast<int>(i);
  if (consecutive) {
    DoubleClassifier l = k;
    l.kmin = pieces[0].value;
    l.kmax = pieces[n - 1].value;
    // The line through the first and last boundaries: y(D_i) = kmin + i ideally.
    l.c = static_cast<double>(n - 2) / (d[n - 1] - d[1]);
    l.c0 = (l.kmin + 1.0) - (l.c * d[1]);
    if (std::isfinite(l.c) && l.c > 0.0 && std::isfinite(l.c0)) {
      double worst = 0.0;
      for (std::size_t i = 1; i < n; ++i) {
        worst = std::max(worst, std::abs((l.c * d[i]) + l.c0 - (l.kmin + static_cast<double>(i))));
      }
      l.eps0 = worst + rounding(l.c0, l.kmax) + 1e-12;
      if (l.eps0 < 0.05) {
        l.all_linear = true;
        l.usable = true;
        return l;
      }
    }
  }
  if (n <= 3) {
    if (n == 3) k.mid = pieces[1].value;
    k.usable = true;  // n == 2: lo == hi, no middle
    return k;
  }
  // Consecutive outputs kmin..kmax in the middle, on a line through the outer thresholds.
  for (std::size_t i = 2; i + 1 < n; ++i) {
    if (pieces[i].value != pieces[1].value + static_cast<int>(i - 1)) return k;
  }
  if (pieces[1].value < 0) return k;
  k.kmin = pieces[1].value;
  k.kmax = pieces[n - 2].value;
  k.c = (k.kmax - k.kmin) / (d[n - 2] - d[1]);
  k.c0 = k.kmin - (k.c * d[1]);
  if (!(std::isfinite(k.c) && k.c > 0.0 && std::isfinite(k.c0))) return k;
  double worst = 0.0;
  for (std::size_t i = 1; i + 1 < n; ++i) {
    worst = std::max(worst, std::abs((k.c * d[i]) + k.c0 - pieces[i].value));
  }
  k.eps0 = worst + rounding(k.c0, k.kmax) + 1e-12;
  if (!(k.eps0 < 0.05)) return k;
  k.linear = true;
  k.usable = true;
  return k;
}

/// Output of a function of a float per block of 4096 consecutive float patterns (bits >> 12),
/// kResolve where the block holds a boundary, NaN or an infinity.
struct FloatTable {
  static constexpr int kShift = 12;
  std::vector<std::int8_t> bins;
};

FloatTable makeFloatTable(const std::vector<Piece>& pieces) {
  FloatTable table;
  constexpr std::uint32_t kBins = 1u << (32 - FloatTable::kShift);
  table.bins.assign(kBins + 3, kResolve);  // 3 bytes of padding for 4-byte gathers
  std::size_t piece = 0;
  const auto pieceOf = [&](std::uint32_t key) {  // keys asked in increasing order
    while (piece + 1 < pieces.size() && pieces[piece + 1].first_key <= key) ++piece;
    return piece;
  };
  const auto fill = [&](std::uint32_t bin) {
    const std::uint32_t first = bin << FloatTable::kShift;
    const std::uint32_t last = first | ((1u << FloatTable::kShift) - 1u);
    if ((first & 0x7F800000u) == 0x7F800000u) return;  // infinities and NaNs
    const std::uint32_t k1 = keyOfBits(first);
    const std::uint32_t k2 = keyOfBits(last);
    const std::size_t p1 = pieceOf(std::min(k1, k2));
    const std::size_t p2 = pieceOf(std::max(k1, k2));
    if (p1 == p2) table.bins[bin] = pieces[p1].value;
  };
  // Negative floats from -NaN to -0 (keys increasing), then positive from +0.
  for (std::uint32_t bin = kBins; bin-- > kBins / 2;) fill(bin);
  for (std::uint32_t bin = 0; bin < kBins / 2; ++bin) fill(bin);
  return table;
}

/// A scaling with the reference's kRaw thresholds written as full_scale 1.
OccupancyScaling normalized(const OccupancyScaling& scaling) {
  if (scaling.thresholds && scaling.thresholds->mode == ThresholdMode::kRaw) return OccupancyScaling{1.0f, std::nullopt};
  return scaling;
}

std::int8_t scaledValue(float value, const OccupancyScaling& scaling) {
  return scaling.thresholds ? thresholdedOccupancyValue(value, *scaling.thresholds)
                            : occupancyValue(value, scaling.full_scale);
}

/// What one scaling needs, built once and shared (the static table lazily: 1 MiB).
struct ScalingTables {
  OccupancyScaling scaling;
  bool fast = false;  // false: every cell the reference's way
  DoubleClassifier classifier;
  std::once_flag static_once;
  FloatTable static_table;
};

bool sameScaling(const OccupancyScaling& a, const OccupancyScaling& b) {
  if (bitsOf(a.full_scale) != bitsOf(b.full_scale) || a.thresholds.has_value() != b.thresholds.has_value()) {
    return false;
  }
  if (!a.thresholds) return true;
  return a.thresholds->mode == b.thresholds->mode && a.thresholds->occupied_thresh == b.thresholds->occupied_thresh &&
         a.thresholds->free_thresh == b.thresholds->free_thresh;
}

std::shared_ptr<ScalingTables> tablesFor(const OccupancyScaling& raw_scaling) {
  static std::mutex mutex;
  static std::vector<std::shared_ptr<ScalingTables>> cache;
  const OccupancyScaling scaling = normalized(raw_scaling);
  const std::lock_guard<std::mutex> lock(mutex);
  for (const auto& tables : cache) {
    if (sameScaling(tables->scaling, scaling)) return tables;
  }
  auto tables = std::make_shared<ScalingTables>();
  tables->scaling = scaling;
  bool valid = std::isfinite(scaling.full_scale) && scaling.full_scale > 0.0f;
  if (scaling.thresholds) {
    try {
      scaling.thresholds->validate();
    } catch (const std::invalid_argument&) {
      valid = false;  // no piece structure to rely on: the reference's way
    }
  }
  if (valid) {
    tables->classifier = makeDoubleClassifier(findPieces([&](float v) { return scaledValue(v, scaling); }));
    tables->fast = tables->classifier.usable;
  }
  if (cache.size() >= 16) cache.erase(cache.begin());
  cache.push_back(tables);
  return tables;
}

const FloatTable& staticTable(ScalingTables& tables) {
  std::call_once(tables.static_once, [&tables] {
    const OccupancyScaling scaling = tables.scaling;
    tables.static_table = makeFloatTable(findPieces([&](float log_odds) {
      return scaledValue(static_cast<float>(logOddsToProbability(log_odds)), scaling);
    }));
  });
  return tables.static_table;
}

/// The reference for one cell (evaluateLayer's value, then the scaling). Not inlined into
/// the vector code, so it is compiled exactly like the reference.
__attribute__((noinline)) std::int8_t referenceOccupancy(const CellGrid::Tile& tile, int i, Layer layer,
                                                         std::int64_t step, std::int64_t horizon_steps,
                                                         const OccupancyScaling& scaling) {
  if (tile.last_step[i] == kNeverObserved) return -1;
  return scaledValue(cellValue(tile, i, layer, step, horizon_steps), scaling);
}

// ---- The vector loop ----------------------------------------------------------------
//
// Error bound of the prediction (u = 2^-53). The reference computes
//   x_ref = pi + L_ref * (p - pi),  L_ref = pow(|lambda|, k) (sign by parity), or
//   exp(k log1p(-(p_of + p_fo))) when |lambda| is within 1e-3 of 1,
// with the same lambda = (1 - p_of) - p_fo, pi and p - pi as here (same operations on the
// same doubles: bit-identical). Here L = lambda^k by repeated squaring: lambda^(2^j) carries
// a relative error <= (2^j - 1) u, the product <= (k + bits(k)) u. pow is within 1 ulp
// (budget 4u); the log1p form differs from lambda^k by <= k * 3.01u (1 - fl(p_of + p_fo)
// against fl(fl(1 - p_of) - p_fo), each within 2u of 1 - p_of - p_fo, for |lambda| >= 0.999)
// plus the rounding of log1p, the product and exp: <= 10u |k ln L| relative, i.e.
// <= 10u/e absolute in L. So |L - L_ref| <= |L| (5k + 64) u + 4u, and with the roundings of
// L (p - pi) and of the sum (a few u; FMA or not),
//   |x - x_ref| <= |L (p - pi)| (5k + 70) u + 10u   <   m = |L (p - pi)| (16k + 512) u + 64u
// (AVX2, pi by division as the reference; the AVX-512 loop takes pi from a reciprocal,
// which adds <= 10u, and uses + 128u). Inputs are required in [0, 1] (else the reference
// decides); 0 < k < 2^30. The tests take the margin away and see cells at the boundaries
// come out wrong; they pass with a quarter of the k term, so the bound has room.

enum class Kind { kPredict, kStationary, kFloat, kStatic };

struct RowJob {
  const CellGrid* grid = nullptr;
  Layer layer = Layer::kBelief;
  CellBox box;
  std::int64_t step = 0;
  std::int64_t horizon_steps = 0;
  OccupancyScaling scaling;
  bool fast = false;  // the vector loop; else every observed cell the reference's way
  bool avx512 = false;  // the prediction's AVX-512 loop
  Kind kind = Kind::kPredict;
  std::int32_t predict_step = 0;   // step (+ horizon) of the prediction
  std::int32_t min_last_step = 0;  // cells with a last step outside [min, max]: the reference
  std::int32_t max_last_step = 0;
  const DoubleClassifier* classifier = nullptr;
  const std::int8_t* static_bins = nullptr;
  std::int8_t* out = nullptr;
};

#if DOG_LAYERS_AVX2
#define DOG_AVX2 __attribute__((target("avx2,fma")))
#define DOG_AVX2_INLINE inline __attribute__((always_inline, target("avx2,fma")))

/// The classifier in four lanes.
struct ClassifierLanes {
  __m256d lo, hi, c, c0, eps0, kmin, kmax, kmax_half, y_min, y_max;
  __m256i below, above, mid;  // int64 lanes
  bool linear;
  bool all_linear;
};

DOG_AVX2_INLINE ClassifierLanes lanesOf(const DoubleClassifier& k) {
  ClassifierLanes l;
  l.lo = _mm256_set1_pd(k.lo);
  l.hi = _mm256_set1_pd(k.hi);
  l.c = _mm256_set1_pd(k.c);
  l.c0 = _mm256_set1_pd(k.c0);
  l.eps0 = _mm256_set1_pd(k.eps0);
  l.kmin = _mm256_set1_pd(k.kmin);
  l.kmax = _mm256_set1_pd(k.kmax);
  l.kmax_half = _mm256_set1_pd(k.kmax + 0.5);
  l.below = _mm256_set1_epi64x(k.below);
  l.above = _mm256_set1_epi64x(k.above);
  l.mid = _mm256_set1_epi64x(k.mid);
  l.y_min = _mm256_set1_pd(k.kmin + 0.5);
  l.y_max = _mm256_set1_pd(k.kmax + 0.5);
  l.linear = k.linear;
  l.all_linear = k.all_linear;
  return l;
}

/// The low 32 bits of four 64-bit lanes (masks or small integers).
DOG_AVX2_INLINE __m128i narrow(__m256i v) {
  return _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(v, _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6)));
}

/// Four doubles x, each within m of the reference's double: the output, or kResolve.
DOG_AVX2_INLINE __m128i classify4(__m256d x, __m256d m, const ClassifierLanes& k) {
  if (k.all_linear) {
    __m256d y = _mm256_fmadd_pd(x, k.c, k.c0);
    y = _mm256_min_pd(k.y_max, _mm256_max_pd(k.y_min, y));  // a NaN stays NaN (the second operand)
    const __m128i k32 = _mm256_cvttpd_epi32(y);            // y > 0: truncation is floor
    // Decided where y is more than eps from the nearest integer (eps < y - floor(y) < 1 - eps).
    const __m256d to_nearest = _mm256_sub_pd(y, _mm256_round_pd(y, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
    const __m256d eps = _mm256_fmadd_pd(m, k.c, k.eps0);
    const __m256d ok = _mm256_cmp_pd(_mm256_andnot_pd(_mm256_set1_pd(-0.0), to_nearest), eps, _CMP_GT_OQ);
    return _mm_blendv_epi8(_mm_set1_epi32(kResolve), k32, narrow(_mm256_castpd_si256(ok)));
  }
  const __m256d x_low = _mm256_sub_pd(x, m);
  const __m256d x_high = _mm256_add_pd(x, m);
  const __m256d below = _mm256_cmp_pd(x_high, k.lo, _CMP_LT_OQ);
  const __m256d above = _mm256_cmp_pd(x_low, k.hi, _CMP_GE_OQ);
  __m256d mid = _mm256_and_pd(_mm256_cmp_pd(x_low, k.lo, _CMP_GE_OQ), _mm256_cmp_pd(x_high, k.hi, _CMP_LT_OQ));
  __m256i mid_value = k.mid;
  if (k.linear) {
    __m256d y = _mm256_fmadd_pd(x, k.c, k.c0);
    y = _mm256_max_pd(y, k.kmin);  // a NaN y becomes kmin (max_pd returns its second operand)
    y = _mm256_min_pd(y, k.kmax_half);
    const __m128i k32 = _mm256_cvttpd_epi32(y);  // y >= kmin >= 0: truncation is floor
    const __m256d kd = _mm256_cvtepi32_pd(k32);
    const __m256d f = _mm256_sub_pd(y, kd);
    const __m256d eps = _mm256_fmadd_pd(m, k.c, k.eps0);
    const __m256d low_ok = _mm256_or_pd(_mm256_cmp_pd(kd, k.kmin, _CMP_LE_OQ), _mm256_cmp_pd(f, eps, _CMP_GE_OQ));
    const __m256d high_ok = _mm256_or_pd(_mm256_cmp_pd(kd, k.kmax, _CMP_GE_OQ),
                                         _mm256_cmp_pd(f, _mm256_sub_pd(_mm256_set1_pd(1.0), eps), _CMP_LT_OQ));
    mid = _mm256_and_pd(mid, _mm256_and_pd(low_ok, high_ok));
    mid_value = _mm256_cvtepi32_epi64(k32);
  }
  __m256i v = _mm256_blendv_epi8(_mm256_set1_epi64x(kResolve), mid_value, _mm256_castpd_si256(mid));
  v = _mm256_blendv_epi8(v, k.above, _mm256_castpd_si256(above));
  v = _mm256_blendv_epi8(v, k.below, _mm256_castpd_si256(below));
  return narrow(v);
}

/// Four cells from offset i of `tile` (stationary and transition layers): outputs
/// (kResolve: undecided) as int32.
template <Kind kKind>
DOG_AVX2_INLINE __m128i cells4(const CellGrid::Tile& tile, int i, const RowJob& job, const ClassifierLanes& k) {
  const __m128i last_step = _mm_loadu_si128(reinterpret_cast<const __m128i*>(tile.last_step.data() + i));
  const __m128i never = _mm_cmpeq_epi32(last_step, _mm_set1_epi32(kNeverObserved));
  const __m256d zero = _mm256_setzero_pd();
  __m128i v;
  if constexpr (kKind == Kind::kStationary) {
    const __m256d p = _mm256_cvtps_pd(_mm_loadu_ps(tile.p_occ.data() + i));
    const __m256d a = _mm256_cvtps_pd(_mm_loadu_ps(tile.p_occ_given_free.data() + i));
    const __m256d b = _mm256_cvtps_pd(_mm_loadu_ps(tile.p_free_given_occ.data() + i));
    const __m256d sum = _mm256_add_pd(a, b);
    // The reference's operations (a static cell keeps its belief): m = 0.
    const __m256d x = _mm256_blendv_pd(_mm256_div_pd(a, sum), p, _mm256_cmp_pd(sum, zero, _CMP_EQ_OQ));
    v = classify4(x, zero, k);
  } else {
    const float* values = job.layer == Layer::kOccGivenFree ? tile.p_occ_given_free.data() : tile.p_free_given_occ.data();
    v = classify4(_mm256_cvtps_pd(_mm_loadu_ps(values + i)), zero, k);
  }
  return _mm_blendv_epi8(v, _mm_set1_epi32(-1), never);
}

/// Eight cells from offset i of `tile` into out[0..8) (all kinds but the prediction).
template <Kind kKind>
DOG_AVX2_INLINE void cells8(const CellGrid::Tile& tile, int i, const RowJob& job, const ClassifierLanes& k,
                            std::int8_t* out) {
  __m128i packed;
  if constexpr (kKind == Kind::kStatic) {
    const __m256i last_step = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(tile.last_step.data() + i));
    const __m256i bits = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(tile.log_odds.data() + i));
    // Four bytes from each bin (the table has 3 bytes of padding); the bin's byte is the lowest.
    __m256i v = _mm256_i32gather_epi32(reinterpret_cast<const int*>(job.static_bins),
                                       _mm256_srli_epi32(bits, FloatTable::kShift), 1);
    v = _mm256_srai_epi32(_mm256_slli_epi32(v, 24), 24);
    v = _mm256_blendv_epi8(v, _mm256_set1_epi32(-1), _mm256_cmpeq_epi32(last_step, _mm256_set1_epi32(kNeverObserved)));
    packed = _mm_packs_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
  } else {
    packed = _mm_packs_epi32(cells4<kKind>(tile, i, job, k), cells4<kKind>(tile, i + 4, job, k));
  }
  _mm_storel_epi64(reinterpret_cast<__m128i*>(out), _mm_packs_epi16(packed, packed));
}

/// Belief / predicted: 16 cells (four vectors of four from start[0..3]) into out[0..16),
/// the squarings of the four vectors side by side (independent chains) for a fixed number
/// of rounds, the bit length of the group's longest gap.
DOG_AVX2_INLINE void predict16(const CellGrid::Tile& tile, const int* start, const RowJob& job,
                               const ClassifierLanes& k, std::int8_t* out) {
  constexpr int kV = 4;
  __m256d p[kV], pi[kV], d[kV], gap_d[kV], trivial[kV], base[kV], power[kV];
  __m256i e[kV];
  __m128i never[kV], sane32[kV];
  const __m256d zero = _mm256_setzero_pd();
  const __m256d one = _mm256_set1_pd(1.0);
  const __m128i unit_bits = _mm_set1_epi32(0x3F800000);  // 1.0f
  __m256i any = _mm256_setzero_si256();
  for (int v = 0; v < kV; ++v) {
    const int i = start[v];
    const __m128i last_step = _mm_loadu_si128(reinterpret_cast<const __m128i*>(tile.last_step.data() + i));
    const __m128i p_bits = _mm_loadu_si128(reinterpret_cast<const __m128i*>(tile.p_occ.data() + i));
    const __m128i a_bits = _mm_loadu_si128(reinterpret_cast<const __m128i*>(tile.p_occ_given_free.data() + i));
    const __m128i b_bits = _mm_loadu_si128(reinterpret_cast<const __m128i*>(tile.p_free_given_occ.data() + i));
    never[v] = _mm_cmpeq_epi32(last_step, _mm_set1_epi32(kNeverObserved));
    // In [0, 1] as floats <=> the patterns, unsigned, at most that of 1.0f (-0 and NaN fail).
    const __m128i largest = _mm_max_epu32(_mm_max_epu32(p_bits, a_bits), b_bits);
    const __m128i in_unit = _mm_cmpeq_epi32(_mm_max_epu32(largest, unit_bits), unit_bits);
    const __m128i fresh = _mm_andnot_si128(_mm_cmpgt_epi32(last_step, _mm_set1_epi32(job.max_last_step)),
                                           _mm_cmpgt_epi32(last_step, _mm_set1_epi32(job.min_last_step - 1)));
    sane32[v] = _mm_and_si128(in_unit, fresh);
    const __m128i gap = _mm_sub_epi32(_mm_set1_epi32(job.predict_step), last_step);  // used where fresh only
    const __m256d a = _mm256_cvtps_pd(_mm_castsi128_ps(a_bits));
    const __m256d b = _mm256_cvtps_pd(_mm_castsi128_ps(b_bits));
    p[v] = _mm256_cvtps_pd(_mm_castsi128_ps(p_bits));
    gap_d[v] = _mm256_cvtepi32_pd(gap);
    const __m256d sum = _mm256_add_pd(a, b);
    trivial[v] = _mm256_or_pd(_mm256_cmp_pd(gap_d[v], zero, _CMP_LE_OQ), _mm256_cmp_pd(sum, zero, _CMP_EQ_OQ));
    base[v] = _mm256_sub_pd(_mm256_sub_pd(one, a), b);  // lambda, as the reference computes it
    pi[v] = _mm256_div_pd(a, sum);
    d[v] = _mm256_sub_pd(p[v], pi[v]);
    power[v] = one;
    // Lanes with nothing to predict (or left to the reference) at exponent 0.
    const __m128i live = _mm_andnot_si128(narrow(_mm256_castpd_si256(trivial[v])), sane32[v]);
    e[v] = _mm256_and_si256(_mm256_cvtepi32_epi64(gap), _mm256_cvtepi32_epi64(live));
    any = _mm256_or_si256(any, e[v]);
  }
  // Rounds: the bit length of the group's longest gap (gaps < 2^30 fit in the low half).
  const __m128i any128 = _mm_or_si128(_mm256_castsi256_si128(any), _mm256_extracti128_si256(any, 1));
  const std::uint32_t all = static_cast<std::uint32_t>(_mm_cvtsi128_si32(_mm_or_si128(any128, _mm_srli_si128(any128, 8))));
  const int rounds = all == 0 ? 0 : 32 - __builtin_clz(all);
  for (int r = 0; r < rounds; ++r) {
    for (int v = 0; v < kV; ++v) {
      const __m256d odd = _mm256_castsi256_pd(_mm256_slli_epi64(e[v], 63));  // sign bit = lowest bit of e
      power[v] = _mm256_blendv_pd(power[v], _mm256_mul_pd(power[v], base[v]), odd);
      base[v] = _mm256_mul_pd(base[v], base[v]);
      e[v] = _mm256_srli_epi64(e[v], 1);
    }
  }
  constexpr double u = std::numeric_limits<double>::epsilon() / 2.0;
  __m128i value[kV];
  for (int v = 0; v < kV; ++v) {
    const __m256d ld = _mm256_mul_pd(power[v], d[v]);
    const __m256d x = _mm256_blendv_pd(_mm256_add_pd(pi[v], ld), p[v], trivial[v]);
    const __m256d bound =
        _mm256_fmadd_pd(_mm256_andnot_pd(_mm256_set1_pd(-0.0), ld),
                        _mm256_fmadd_pd(gap_d[v], _mm256_set1_pd(16.0 * u), _mm256_set1_pd(512.0 * u)),
                        _mm256_set1_pd(64.0 * u));
    const __m128i decided = classify4(x, _mm256_andnot_pd(trivial[v], bound), k);
    value[v] = _mm_blendv_epi8(_mm_blendv_epi8(_mm_set1_epi32(kResolve), decided, sane32[v]), _mm_set1_epi32(-1),
                               never[v]);
  }
  const __m128i low = _mm_packs_epi32(value[0], value[1]);
  const __m128i high = _mm_packs_epi32(value[2], value[3]);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(out), _mm_packs_epi16(low, high));
}

/// The cells [x0, x0 + n) of row y, all in one allocated tile.
template <Kind kKind>
DOG_AVX2 void runAvx2Of(const CellGrid::Tile& tile, std::int32_t x0, std::int32_t y, int n, const RowJob& job,
                        std::int8_t* out) {
  const ClassifierLanes k = lanesOf(*job.classifier);
  const int i0 = CellGrid::offsetOf(x0, y);
  if constexpr (kKind == Kind::kPredict) {
    int j = 0;
    for (; j + 16 <= n; j += 16) {
      const int start[4] = {i0 + j, i0 + j + 4, i0 + j + 8, i0 + j + 12};
      predict16(tile, start, job, k, out + j);
    }
    if (j < n) {
      // The last few: 16 cells of the tile's arrays that include them (forward where the
      // arrays allow, else ending at the run's end); only the run's cells are kept.
      std::int8_t tail[16];
      const int first = (i0 + j + 16 <= CellGrid::kTileCells) ? i0 + j : i0 + n - 16;
      const int start[4] = {first, first + 4, first + 8, first + 12};
      predict16(tile, start, job, k, tail);
      std::memcpy(out + j, tail + (i0 + j - first), static_cast<std::size_t>(n - j));
    }
  } else {
    int j = 0;
    for (; j + 8 <= n; j += 8) cells8<kKind>(tile, i0 + j, job, k, out + j);
    if (j < n) {
      // The last few: eight cells of the tile's arrays that include them (forward where the
      // arrays allow, else ending at the run's end); only the run's cells are kept.
      std::int8_t tail[8];
      const int start = (i0 + j + 8 <= CellGrid::kTileCells) ? i0 + j : i0 + n - 8;
      cells8<kKind>(tile, start, job, k, tail);
      std::memcpy(out + j, tail + (i0 + j - start), static_cast<std::size_t>(n - j));
    }
  }
}

// GCC 12's AVX-512 headers trip -Wmaybe-uninitialized on their own _mm512_undefined_pd().
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#define DOG_AVX512_TARGET "avx512f,avx512dq,avx512vl,avx512bw,avx2,fma"
#define DOG_AVX512 __attribute__((target(DOG_AVX512_TARGET)))
#define DOG_AVX512_INLINE inline __attribute__((always_inline, target(DOG_AVX512_TARGET)))

/// Belief / predicted with AVX-512: 32 cells (four vectors of eight from `first`) into
/// out[0..32). As predict16, with masked multiplies for the squaring and p_of / (p_of + p_fo)
/// from rcp14 and two Newton steps (relative error <= 2^-56 + a few roundings:
/// |pi' - pi| <= 5u, so |x - x_ref| gains <= 10u, inside m). kAllLinear: the 0..100
/// scalings; otherwise the general classifier (map_server's thresholds).
template <bool kAllLinear>
DOG_AVX512_INLINE void predict32(const CellGrid::Tile& tile, int first, const RowJob& job, std::int8_t* out) {
  constexpr int kV = 4;
  const DoubleClassifier& k = *job.classifier;
  __m512d p[kV], pi[kV], d[kV], gap_d[kV], base[kV], power[kV];
  __m512i e[kV];
  __mmask8 trivial[kV], never[kV], sane[kV];
  const __m512d zero = _mm512_setzero_pd();
  const __m512d one = _mm512_set1_pd(1.0);
  const __m256i unit_bits = _mm256_set1_epi32(0x3F800000);  // 1.0f
  __m512i any = _mm512_setzero_si512();
  for (int v = 0; v < kV; ++v) {
    const int i = first + (8 * v);
    const __m256i last_step = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(tile.last_step.data() + i));
    const __m256i p_bits = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(tile.p_occ.data() + i));
    const __m256i a_bits = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(tile.p_occ_given_free.data() + i));
    const __m256i b_bits = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(tile.p_free_given_occ.data() + i));
    never[v] = _mm256_cmpeq_epi32_mask(last_step, _mm256_set1_epi32(kNeverObserved));
    // In [0, 1] as floats <=> the patterns, unsigned, at most that of 1.0f (-0 and NaN fail).
    const __m256i largest = _mm256_max_epu32(_mm256_max_epu32(p_bits, a_bits), b_bits);
    sane[v] = _mm256_cmple_epu32_mask(largest, unit_bits) &
              _mm256_cmpgt_epi32_mask(last_step, _mm256_set1_epi32(job.min_last_step - 1)) &
              _mm256_cmple_epi32_mask(last_step, _mm256_set1_epi32(job.max_last_step));
    const __m256i gap = _mm256_sub_epi32(_mm256_set1_epi32(job.predict_step), last_step);  // used where sane only
    const __m512d a = _mm512_cvtps_pd(_mm256_castsi256_ps(a_bits));
    const __m512d b = _mm512_cvtps_pd(_mm256_castsi256_ps(b_bits));
    p[v] = _mm512_cvtps_pd(_mm256_castsi256_ps(p_bits));
    gap_d[v] = _mm512_cvtepi32_pd(gap);
    const __m512d sum = _mm512_add_pd(a, b);
    trivial[v] = _mm512_cmp_pd_mask(gap_d[v], zero, _CMP_LE_OQ) | _mm512_cmp_pd_mask(sum, zero, _CMP_EQ_OQ);
    base[v] = _mm512_sub_pd(_mm512_sub_pd(one, a), b);  // lambda, as the reference computes it
    __m512d r = _mm512_rcp14_pd(sum);                     // sum is 0 (trivial) or >= 2^-149
    r = _mm512_fmadd_pd(r, _mm512_fnmadd_pd(sum, r, one), r);
    r = _mm512_fmadd_pd(r, _mm512_fnmadd_pd(sum, r, one), r);
    pi[v] = _mm512_mul_pd(a, r);
    d[v] = _mm512_sub_pd(p[v], pi[v]);
    power[v] = one;
    // Lanes with nothing to predict (or left to the reference) at exponent 0.
    e[v] = _mm512_maskz_cvtepi32_epi64(static_cast<__mmask8>(sane[v] & ~trivial[v]), gap);
    any = _mm512_or_si512(any, e[v]);
  }
  const std::uint64_t all = static_cast<std::uint64_t>(_mm512_reduce_or_epi64(any));
  const int rounds = all == 0 ? 0 : 64 - __builtin_clzll(all);
  for (int r = 0; r < rounds; ++r) {
    const __m512i bit = _mm512_set1_epi64(std::int64_t{1} << r);
    for (int v = 0; v < kV; ++v) {
      power[v] = _mm512_mask_mul_pd(power[v], _mm512_test_epi64_mask(e[v], bit), power[v], base[v]);
      base[v] = _mm512_mul_pd(base[v], base[v]);
    }
  }
  constexpr double u = std::numeric_limits<double>::epsilon() / 2.0;
  const __m512d c = _mm512_set1_pd(k.c);
  const __m512d c0 = _mm512_set1_pd(k.c0);
  const __m512d eps0 = _mm512_set1_pd(k.eps0);
  const __m512d y_min = _mm512_set1_pd(k.kmin + 0.5);
  const __m512d y_max = _mm512_set1_pd(k.kmax + 0.5);
  const __m512d lo = _mm512_set1_pd(k.lo);
  const __m512d hi = _mm512_set1_pd(k.hi);
  for (int v = 0; v < kV; ++v) {
    const __m512d ld = _mm512_mul_pd(power[v], d[v]);
    const __m512d x = _mm512_mask_blend_pd(trivial[v], _mm512_add_pd(pi[v], ld), p[v]);
    const __m512d m =
        _mm512_fmadd_pd(_mm512_abs_pd(ld), _mm512_fmadd_pd(gap_d[v], _mm512_set1_pd(16.0 * u), _mm512_set1_pd(512.0 * u)),
                        _mm512_set1_pd(128.0 * u));
    // floor(y) decided where y is more than eps = c m + eps0 (eps0 where x is exact) from
    // the nearest integer, y clamped to [kmin + 1/2, kmax + 1/2] (classify4's first branch);
    // in general between the outer thresholds only (classify4's second).
    const __m512d eps = _mm512_mask3_fmadd_pd(m, c, eps0, static_cast<__mmask8>(~trivial[v]));
    __m256i value;
    if constexpr (kAllLinear) {
      __m512d y = _mm512_fmadd_pd(x, c, c0);
      y = _mm512_min_pd(y_max, _mm512_max_pd(y_min, y));
      const __m256i k32 = _mm512_cvttpd_epi32(y);
      const __m512d to_nearest = _mm512_reduce_pd(y, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);  // y - round(y), exact
      const __mmask8 ok = _mm512_cmp_pd_mask(_mm512_abs_pd(to_nearest), eps, _CMP_GT_OQ) & sane[v];
      value = _mm256_mask_blend_epi32(ok, _mm256_set1_epi32(kResolve), k32);
    } else {
      const __m512d m_or_zero = _mm512_maskz_mov_pd(static_cast<__mmask8>(~trivial[v]), m);
      const __m512d x_low = _mm512_sub_pd(x, m_or_zero);
      const __m512d x_high = _mm512_add_pd(x, m_or_zero);
      const __mmask8 below = _mm512_cmp_pd_mask(x_high, lo, _CMP_LT_OQ);
      const __mmask8 above = _mm512_cmp_pd_mask(x_low, hi, _CMP_GE_OQ);
      __mmask8 mid = _mm512_cmp_pd_mask(x_low, lo, _CMP_GE_OQ) & _mm512_cmp_pd_mask(x_high, hi, _CMP_LT_OQ);
      __m256i mid_value = _mm256_set1_epi32(k.mid);
      if (k.linear) {
        __m512d y = _mm512_fmadd_pd(x, c, c0);
        y = _mm512_min_pd(y_max, _mm512_max_pd(y_min, y));
        mid_value = _mm512_cvttpd_epi32(y);
        const __m512d to_nearest = _mm512_reduce_pd(y, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
        mid &= _mm512_cmp_pd_mask(_mm512_abs_pd(to_nearest), eps, _CMP_GT_OQ);
      }
      value = _mm256_mask_blend_epi32(mid, _mm256_set1_epi32(kResolve), mid_value);
      value = _mm256_mask_blend_epi32(above, value, _mm256_set1_epi32(k.above));
      value = _mm256_mask_blend_epi32(below, value, _mm256_set1_epi32(k.below));
      value = _mm256_mask_blend_epi32(sane[v], _mm256_set1_epi32(kResolve), value);
    }
    value = _mm256_mask_blend_epi32(never[v], value, _mm256_set1_epi32(-1));
    _mm_storel_epi64(reinterpret_cast<__m128i*>(out + (8 * v)), _mm256_cvtsepi32_epi8(value));
  }
}

/// The cells [x0, x0 + n) of row y, all in one allocated tile (belief / predicted).
DOG_AVX512 void predictRunAvx512(const CellGrid::Tile& tile, std::int32_t x0, std::int32_t y, int n,
                                 const RowJob& job, std::int8_t* out) {
  const int i0 = CellGrid::offsetOf(x0, y);
  int j = 0;
  const bool all_linear = job.classifier->all_linear;
  for (; j + 32 <= n; j += 32) {
    if (all_linear) {
      predict32<true>(tile, i0 + j, job, out + j);
    } else {
      predict32<false>(tile, i0 + j, job, out + j);
    }
  }
  if (j < n) {
    // The last few: 32 cells of the tile's arrays that include them (forward where the
    // arrays allow, else ending at the run's end); only the run's cells are kept.
    std::int8_t tail[32];
    const int first = (i0 + j + 32 <= CellGrid::kTileCells) ? i0 + j : i0 + n - 32;
    if (all_linear) {
      predict32<true>(tile, first, job, tail);
    } else {
      predict32<false>(tile, first, job, tail);
    }
    std::memcpy(out + j, tail + (i0 + j - first), static_cast<std::size_t>(n - j));
  }
}

#pragma GCC diagnostic pop

bool cpuHasAvx512() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
         __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512bw");
}

DOG_AVX2 void runAvx2(const CellGrid::Tile& tile, std::int32_t x0, std::int32_t y, int n, const RowJob& job,
                      std::int8_t* out) {
  switch (job.kind) {
    case Kind::kPredict:
      if (job.avx512) {
        predictRunAvx512(tile, x0, y, n, job, out);
      } else {
        runAvx2Of<Kind::kPredict>(tile, x0, y, n, job, out);
      }
      break;
    case Kind::kStationary:
      runAvx2Of<Kind::kStationary>(tile, x0, y, n, job, out);
      break;
    case Kind::kFloat:
      runAvx2Of<Kind::kFloat>(tile, x0, y, n, job, out);
      break;
    case Kind::kStatic:
      runAvx2Of<Kind::kStatic>(tile, x0, y, n, job, out);
      break;
  }
}

bool cpuHasAvx2() {
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}
#else
bool cpuHasAvx2() { return false; }
bool cpuHasAvx512() { return false; }
#endif

/// Rows [y_begin, y_end) of the box, within one tile row (the block's cells are read tile by
/// tile, as they lie in memory), then the cells left to the reference.
void fillBlock(const RowJob& job, std::int64_t y_begin, std::int64_t y_end) {
  const CellBox& box = job.box;
  const std::int64_t width = box.width();
  std::int8_t* const first_row = job.out + static_cast<std::size_t>((y_begin - box.min_y) * width);
  for (std::int32_t x = box.min_x; x <= box.max_x;) {
    const std::int32_t run_end = std::min<std::int32_t>(box.max_x, (x | (CellGrid::kTileSize - 1)));
    const int n = static_cast<int>(std::int64_t{run_end} - x + 1);
    std::int8_t* out = first_row + (x - box.min_x);
    for (std::int64_t row_y = y_begin; row_y < y_end; ++row_y, out += width) {
      const auto y = static_cast<std::int32_t>(row_y);
      const CellGrid::Tile* tile = job.grid->findTile(x, y);
      if (tile == nullptr) {
        std::memset(out, -1, static_cast<std::size_t>(n));
      } else if (!job.fast) {
        std::memset(out, kResolve, static_cast<std::size_t>(n));
      } else {
#if DOG_LAYERS_AVX2
        runAvx2(*tile, x, y, n, job, out);
#endif
      }
    }
    if (run_end == std::numeric_limits<std::int32_t>::max()) break;
    x = run_end + 1;
  }
  // The cells the fast path left: the reference's way.
  std::int8_t* row = first_row;
  for (std::int64_t row_y = y_begin; row_y < y_end; ++row_y, row += width) {
    const auto y = static_cast<std::int32_t>(row_y);
    for (void* hit = std::memchr(row, static_cast<unsigned char>(kResolve), static_cast<std::size_t>(width));
         hit != nullptr;) {
      std::int8_t* cell = static_cast<std::int8_t*>(hit);
      const std::int32_t x = static_cast<std::int32_t>(box.min_x + (cell - row));
      *cell = referenceOccupancy(*job.grid->findTile(x, y), CellGrid::offsetOf(x, y), job.layer, job.step,
                                 job.horizon_steps, job.scaling);
      const std::size_t rest = static_cast<std::size_t>(width - (cell - row) - 1);
      hit = rest == 0 ? nullptr : std::memchr(cell + 1, static_cast<unsigned char>(kResolve), rest);
    }
  }
}

std::atomic<int> g_layer_kernel{static_cast<int>(LayerKernel::kAuto)};

}  // namespace

void setLayerKernel(LayerKernel kernel) { g_layer_kernel = static_cast<int>(kernel); }

namespace {

/// layerOccupancy into out[0 .. width * height) (row-major over a non-empty box).
void fillOccupancy(const CellGrid& grid, Layer layer, std::int64_t step, std::int64_t horizon_steps,
                   const CellBox& box, const OccupancyScaling& scaling, std::int8_t* out, unsigned threads) {
  const std::shared_ptr<ScalingTables> tables = tablesFor(scaling);
  RowJob job;
  job.grid = &grid;
  job.layer = layer;
  job.box = box;
  job.step = step;
  job.horizon_steps = horizon_steps;
  job.scaling = tables->scaling;
  static const bool avx2 = cpuHasAvx2();
  static const bool avx512 = avx2 && cpuHasAvx512();
  const auto kernel = static_cast<LayerKernel>(g_layer_kernel.load());
  job.fast = tables->fast && avx2 && kernel != LayerKernel::kReference;
  job.avx512 = avx512 && kernel == LayerKernel::kAuto;
  job.classifier = &tables->classifier;
  job.out = out;
  switch (layer) {
    case Layer::kBelief:
    case Layer::kPredicted: {
      job.kind = Kind::kPredict;
      const std::int64_t predict_step = step + (layer == Layer::kPredicted ? horizon_steps : 0);
      constexpr std::int64_t kMaxGap = std::int64_t{1} << 30;
      constexpr std::int64_t kMin = std::numeric_limits<std::int32_t>::min();
      constexpr std::int64_t kMax = std::numeric_limits<std::int32_t>::max();
      if (predict_step <= kMin || predict_step > kMax) {
        job.fast = false;
      } else {
        job.predict_step = static_cast<std::int32_t>(predict_step);
        job.min_last_step = static_cast<std::int32_t>(std::max(predict_step - kMaxGap + 1, kMin + 1));
        job.max_last_step = static_cast<std::int32_t>(std::min(predict_step + kMaxGap, kMax));
      }
      break;
    }
    case Layer::kStationary:
      job.kind = Kind::kStationary;
      break;
    case Layer::kOccGivenFree:
    case Layer::kFreeGivenOcc:
      job.kind = Kind::kFloat;
      break;
    case Layer::kStatic:
      job.kind = Kind::kStatic;
      if (job.fast) job.static_bins = staticTable(*tables).bins.data();
      break;
  }
  // Blocks of rows, one tile row each (cut at multiples of 64), handed out in order; small
  // boxes on this thread alone.
  constexpr std::int64_t kBlockRows = CellGrid::kTileSize;
  const std::int64_t first_block = static_cast<std::int64_t>(box.min_y) >> CellGrid::kTileBits;
  const std::int64_t blocks = (static_cast<std::int64_t>(box.max_y) >> CellGrid::kTileBits) - first_block + 1;
  if (threads == 0) threads = std::max(1U, std::thread::hardware_concurrency());
  if (box.width() * box.height() < std::int64_t{512} * 512) threads = 1;
  threads = static_cast<unsigned>(std::min<std::int64_t>(threads, blocks));
  std::atomic<std::int64_t> next{0};
  runOnThreads(threads, [&] {
    for (std::int64_t b = next++; b < blocks; b = next++) {
      const std::int64_t block_y = (first_block + b) * kBlockRows;
      fillBlock(job, std::max<std::int64_t>(box.min_y, block_y),
                std::min<std::int64_t>(std::int64_t{box.max_y} + 1, block_y + kBlockRows));
    }
  });
}

std::uint64_t tileKey(std::int32_t tile_x, std::int32_t tile_y) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(tile_x)) << 32) | static_cast<std::uint32_t>(tile_y);
}

unsigned threadsFor(unsigned threads) { return threads == 0 ? std::max(1U, std::thread::hardware_concurrency()) : threads; }

}  // namespace

void layerOccupancy(const CellGrid& grid, Layer layer, std::int64_t step, std::int64_t horizon_steps,
                    const CellBox& box, const OccupancyScaling& scaling, std::vector<std::int8_t>* occupancy,
                    unsigned threads) {
  // Every value is written (unallocated tiles as -1): no fill first.
  occupancy->resize(static_cast<std::size_t>(box.width() * box.height()));
  if (box.empty()) return;
  fillOccupancy(grid, layer, step, horizon_steps, box, scaling, occupancy->data(), threads);
}

// ---- LayerTileCache -----------------------------------------------------------------

void TileVersions::bump(std::int32_t tile_x, std::int32_t tile_y) { versions_[tileKey(tile_x, tile_y)] = ++counter_; }

std::uint64_t TileVersions::version(std::int32_t tile_x, std::int32_t tile_y) const {
  const auto it = versions_.find(tileKey(tile_x, tile_y));
  return std::max(epoch_, it == versions_.end() ? std::uint64_t{0} : it->second);
}

struct LayerTileCache::Entry {
  const CellGrid::Tile* tile = nullptr;  // the tile the values were computed from
  std::uint64_t version = 0;
  bool valid = false;
  std::array<std::int8_t, CellGrid::kTileCells> values;  // row-major, 64 x 64
};

LayerTileCache::LayerTileCache(Layer layer, const OccupancyScaling& scaling) : layer_(layer), scaling_(scaling) {
  if (layer == Layer::kBelief || layer == Layer::kPredicted) {
    throw std::invalid_argument("LayerTileCache: " + layerName(layer) + " changes with the step; it cannot be cached");
  }
}
LayerTileCache::~LayerTileCache() = default;
LayerTileCache::LayerTileCache(LayerTileCache&&) noexcept = default;
LayerTileCache& LayerTileCache::operator=(LayerTileCache&&) noexcept = default;

void LayerTileCache::occupancy(const CellGrid& grid, const TileVersions& versions, const CellBox& box,
                               std::vector<std::int8_t>* occupancy, unsigned threads) {
  occupancy->resize(static_cast<std::size_t>(box.width() * box.height()));
  last_computed_ = 0;
  if (box.empty()) return;
  constexpr int kBits = CellGrid::kTileBits;
  const std::int32_t tx0 = box.min_x >> kBits;
  const std::int32_t ty0 = box.min_y >> kBits;
  const std::int64_t tiles_w = std::int64_t{box.max_x >> kBits} - tx0 + 1;
  const std::int64_t tiles_h = std::int64_t{box.max_y >> kBits} - ty0 + 1;
  // The entries of the box's tiles (nullptr: no tile in the grid), and those to compute.
  std::vector<Entry*> entries(static_cast<std::size_t>(tiles_w * tiles_h), nullptr);
  std::vector<std::pair<Entry*, std::uint64_t>> stale;
  for (std::int64_t ty = 0; ty < tiles_h; ++ty) {
    for (std::int64_t tx = 0; tx < tiles_w; ++tx) {
      const auto tile_x = static_cast<std::int32_t>(tx0 + tx);
      const auto tile_y = static_cast<std::int32_t>(ty0 + ty);
      const CellGrid::Tile* tile = grid.findTile(tile_x * CellGrid::kTileSize, tile_y * CellGrid::kTileSize);
      if (tile == nullptr) continue;
      std::unique_ptr<Entry>& entry = entries_[tileKey(tile_x, tile_y)];
      if (!entry) entry = std::make_unique<Entry>();
      const std::uint64_t version = versions.version(tile_x, tile_y);
      if (!(entry->valid && entry->tile == tile && entry->version == version)) {
        entry->tile = tile;
        entry->version = version;
        entry->valid = false;
        stale.emplace_back(entry.get(), tileKey(tile_x, tile_y));
      }
      entries[static_cast<std::size_t>((ty * tiles_w) + tx)] = entry.get();
    }
  }
  last_computed_ = stale.size();
  threads = threadsFor(threads);
  {
    std::atomic<std::size_t> next{0};
    runOnThreads(std::min<std::size_t>(threads, (stale.size() + 15) / 16), [&] {
      for (std::size_t i = next++; i < stale.size(); i = next++) {
        const auto tile_x = static_cast<std::int32_t>(stale[i].second >> 32);
        const auto tile_y = static_cast<std::int32_t>(stale[i].second & 0xFFFFFFFFu);
        CellBox tile_box;
        tile_box.include(tile_x * CellGrid::kTileSize, tile_y * CellGrid::kTileSize);
        tile_box.include((tile_x * CellGrid::kTileSize) + CellGrid::kTileSize - 1,
                         (tile_y * CellGrid::kTileSize) + CellGrid::kTileSize - 1);
        fillOccupancy(grid, layer_, 0, 0, tile_box, scaling_, stale[i].first->values.data(), 1);
        stale[i].first->valid = true;
      }
    });
  }
  // The copy, by rows of tiles.
  const std::int64_t width = box.width();
  std::atomic<std::int64_t> next{0};
  runOnThreads(box.width() * box.height() < std::int64_t{512} * 512 ? 1 : std::min<std::int64_t>(threads, tiles_h), [&] {
    for (std::int64_t ty = next++; ty < tiles_h; ty = next++) {
      const std::int64_t row_begin = std::max<std::int64_t>(box.min_y, (ty0 + ty) * CellGrid::kTileSize);
      const std::int64_t row_end =
          std::min<std::int64_t>(std::int64_t{box.max_y} + 1, ((ty0 + ty) + 1) * CellGrid::kTileSize);
      for (std::int64_t tx = 0; tx < tiles_w; ++tx) {
        const Entry* entry = entries[static_cast<std::size_t>((ty * tiles_w) + tx)];
        const std::int64_t x_begin = std::max<std::int64_t>(box.min_x, (tx0 + tx) * CellGrid::kTileSize);
        const std::int64_t x_end = std::min<std::int64_t>(std::int64_t{box.max_x} + 1, ((tx0 + tx) + 1) * CellGrid::kTileSize);
        const auto n = static_cast<std::size_t>(x_end - x_begin);
        for (std::int64_t y = row_begin; y < row_end; ++y) {
          std::int8_t* out = occupancy->data() + ((y - box.min_y) * width) + (x_begin - box.min_x);
          if (entry == nullptr) {
            std::memset(out, -1, n);
          } else {
            std::memcpy(out, entry->values.data() + ((y & (CellGrid::kTileSize - 1)) * CellGrid::kTileSize) +
                                 (x_begin & (CellGrid::kTileSize - 1)),
                        n);
          }
        }
      }
    }
  });
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
