#include "block_cholesky.hpp"

#include <Eigen/Cholesky>
#include <Eigen/OrderingMethods>
#include <Eigen/SparseCore>
#include <algorithm>

namespace rekon::optimiser::detail {
namespace {

// c -= a * b^T for column-major 6x6 blocks, in plain loops so that the
// compiler vectorises them for the target of the function it is inlined into.
inline void subtractProductTransposed(double* __restrict c, const double* __restrict a, const double* __restrict b) {
  for (int j = 0; j < 6; ++j) {
    for (int k = 0; k < 6; ++k) {
      const double bjk = b[k * 6 + j];
      for (int i = 0; i < 6; ++i) c[j * 6 + i] -= a[k * 6 + i] * bjk;
    }
  }
}

// The Schur update of one factored column: for every pair (r1 >= r2) of its
// rows, block (r1, r2) -= L(r1, p) L(r2, p)^T. Every such pair is in the
// pattern of column r2 (the fill property), found by walking r2's rows. This
// is nearly all of the factorisation's time; the x86-64-v3 clone (AVX2 + FMA)
// runs it about twice as fast as the baseline SSE2 one and is picked at load
// time where the CPU has it.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target_clones("arch=haswell", "default")))
#endif
void schurUpdate(int begin, int end, const int* col_start, const int* col_rows, Block6* l_blocks, Block6* l_diag) {
  for (int k2 = begin; k2 < end; ++k2) {
    const int r2 = col_rows[k2];
    const double* l2 = l_blocks[k2].data();
    subtractProductTransposed(l_diag[r2].data(), l2, l2);
    int t = col_start[r2];
    for (int k1 = k2 + 1; k1 < end; ++k1) {
      const int r1 = col_rows[k1];
      while (col_rows[t] != r1) ++t;
      subtractProductTransposed(l_blocks[t].data(), l_blocks[k1].data(), l2);
    }
  }
}

int64_t pairKey(int i, int j) {
  const int lo = std::min(i, j), hi = std::max(i, j);
  return (static_cast<int64_t>(lo) << 32) | static_cast<int64_t>(hi);
}

// The neighbours of each block row in the pattern, both ways round.
std::vector<std::vector<int>> blockAdjacency(int n, const std::vector<std::pair<int, int>>& pairs) {
  std::vector<std::vector<int>> adjacency(static_cast<size_t>(n));
  for (const auto& [i, j] : pairs) {
    adjacency[static_cast<size_t>(i)].push_back(j);
    adjacency[static_cast<size_t>(j)].push_back(i);
  }
  return adjacency;
}

}  // namespace

void BlockCholesky::analyse(int n, const std::vector<std::pair<int, int>>& pairs) {
  n_ = n;
  keepUniquePairs(pairs);
  const std::vector<std::vector<int>> adjacency = blockAdjacency(n, pair_rows_);
  orderToReduceFill(adjacency);
  analyseFactorPattern(adjacency);
  l_blocks_.resize(col_rows_.size());
  l_diag_.resize(static_cast<size_t>(n));
  placePairBlocks();
  diag_.assign(static_cast<size_t>(n), Block6::Zero());
  off_.assign(pair_rows_.size(), Block6::Zero());
}

void BlockCholesky::keepUniquePairs(const std::vector<std::pair<int, int>>& pairs) {
  // Each pair is remembered in its first orientation.
  std::vector<std::pair<int64_t, int>> keyed;
  keyed.reserve(pairs.size());
  for (size_t k = 0; k < pairs.size(); ++k) keyed.emplace_back(pairKey(pairs[k].first, pairs[k].second), static_cast<int>(k));
  std::sort(keyed.begin(), keyed.end());
  pair_keys_.clear();
  pair_key_index_.clear();
  pair_rows_.clear();
  for (const auto& [key, k] : keyed) {
    if (!pair_keys_.empty() && pair_keys_.back() == key) continue;
    pair_keys_.push_back(key);
    pair_key_index_.push_back(static_cast<int>(pair_rows_.size()));
    pair_rows_.push_back(pairs[static_cast<size_t>(k)]);
  }
}

void BlockCholesky::orderToReduceFill(const std::vector<std::vector<int>>& adjacency) {
  // AMD on the block graph, as CHOLMOD would use.
  std::vector<Eigen::Triplet<double, int>> triplets;
  for (int i = 0; i < n_; ++i) {
    triplets.emplace_back(i, i, 1.0);
    for (int j : adjacency[static_cast<size_t>(i)]) triplets.emplace_back(i, j, 1.0);
  }
  Eigen::SparseMatrix<double, Eigen::ColMajor, int> pattern(n_, n_);
  pattern.setFromTriplets(triplets.begin(), triplets.end());
  Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> amd;
  Eigen::AMDOrdering<int>()(pattern, amd);
  perm_.assign(amd.indices().data(), amd.indices().data() + n_);
  iperm_.assign(static_cast<size_t>(n_), 0);
  for (int p = 0; p < n_; ++p) iperm_[static_cast<size_t>(perm_[static_cast<size_t>(p)])] = p;
}

void BlockCholesky::analyseFactorPattern(const std::vector<std::vector<int>>& adjacency) {
  // Column p's rows are its own lower neighbours and those of its children in
  // the elimination tree, less p itself.
  std::vector<std::vector<int>> children(static_cast<size_t>(n_));
  std::vector<int> mark(static_cast<size_t>(n_), -1);
  col_start_.assign(1, 0);
  col_rows_.clear();
  std::vector<int> rows;
  for (int p = 0; p < n_; ++p) {
    rows.clear();
    mark[static_cast<size_t>(p)] = p;
    for (int j : adjacency[static_cast<size_t>(perm_[static_cast<size_t>(p)])]) {
      const int q = iperm_[static_cast<size_t>(j)];
      if (q > p && mark[static_cast<size_t>(q)] != p) {
        mark[static_cast<size_t>(q)] = p;
        rows.push_back(q);
      }
    }
    for (int c : children[static_cast<size_t>(p)]) {
      for (int k = col_start_[static_cast<size_t>(c)]; k < col_start_[static_cast<size_t>(c) + 1]; ++k) {
        const int q = col_rows_[static_cast<size_t>(k)];
        if (mark[static_cast<size_t>(q)] != p) {
          mark[static_cast<size_t>(q)] = p;
          rows.push_back(q);
        }
      }
    }
    std::sort(rows.begin(), rows.end());
    col_rows_.insert(col_rows_.end(), rows.begin(), rows.end());
    col_start_.push_back(static_cast<int>(col_rows_.size()));
    if (!rows.empty()) children[static_cast<size_t>(rows.front())].push_back(p);
  }
}

void BlockCholesky::placePairBlocks() {
  pair_slot_.resize(pair_rows_.size());
  pair_transposed_.resize(pair_rows_.size());
  for (size_t k = 0; k < pair_rows_.size(); ++k) {
    const int a = iperm_[static_cast<size_t>(pair_rows_[k].first)], b = iperm_[static_cast<size_t>(pair_rows_[k].second)];
    const int row = std::max(a, b), col = std::min(a, b);
    const auto begin = col_rows_.begin() + col_start_[static_cast<size_t>(col)];
    const auto end = col_rows_.begin() + col_start_[static_cast<size_t>(col) + 1];
    pair_slot_[k] = static_cast<int>(std::lower_bound(begin, end, row) - col_rows_.begin());
    pair_transposed_[k] = a < b;  // stored A(i, j) sits above the diagonal in the new order
  }
}

int BlockCholesky::pairIndex(int i, int j) const {
  const auto it = std::lower_bound(pair_keys_.begin(), pair_keys_.end(), pairKey(i, j));
  if (it == pair_keys_.end() || *it != pairKey(i, j)) return -1;
  return pair_key_index_[static_cast<size_t>(it - pair_keys_.begin())];
}

void BlockCholesky::setZero() {
  for (Block6& b : diag_) b.setZero();
  for (Block6& b : off_) b.setZero();
}

bool BlockCholesky::factorize(double damping) {
  for (int p = 0; p < n_; ++p) {
    Block6& d = l_diag_[static_cast<size_t>(p)];
    d = diag_[static_cast<size_t>(perm_[static_cast<size_t>(p)])];
    d.diagonal() *= 1.0 + damping;
  }
  for (Block6& b : l_blocks_) b.setZero();
  for (size_t k = 0; k < off_.size(); ++k) {
    Block6& slot = l_blocks_[static_cast<size_t>(pair_slot_[k])];
    if (pair_transposed_[k])
      slot += off_[k].transpose();
    else
      slot += off_[k];
  }
  // Right-looking: factor column p, then subtract its outer products from the
  // columns to its right.
  for (int p = 0; p < n_; ++p) {
    Eigen::LLT<Block6> llt(l_diag_[static_cast<size_t>(p)]);
    if (llt.info() != Eigen::Success) return false;
    Block6& lpp = l_diag_[static_cast<size_t>(p)];
    lpp = llt.matrixL();
    const Block6 lpp_inv_t = lpp.triangularView<Eigen::Lower>().solve(Block6::Identity()).transpose();
    const int begin = col_start_[static_cast<size_t>(p)], end = col_start_[static_cast<size_t>(p) + 1];
    for (int k = begin; k < end; ++k) {
      Block6& b = l_blocks_[static_cast<size_t>(k)];
      b = (b * lpp_inv_t).eval();
    }
    schurUpdate(begin, end, col_start_.data(), col_rows_.data(), l_blocks_.data(), l_diag_.data());
  }
  return true;
}

void BlockCholesky::solve(Eigen::VectorXd& b) const {
  using Vec6 = Eigen::Matrix<double, 6, 1>;
  Eigen::VectorXd y(6 * n_);
  for (int p = 0; p < n_; ++p) y.segment<6>(6 * p) = b.segment<6>(6 * perm_[static_cast<size_t>(p)]);
  for (int p = 0; p < n_; ++p) {
    Vec6 yp = l_diag_[static_cast<size_t>(p)].triangularView<Eigen::Lower>().solve(y.segment<6>(6 * p));
    y.segment<6>(6 * p) = yp;
    for (int k = col_start_[static_cast<size_t>(p)]; k < col_start_[static_cast<size_t>(p) + 1]; ++k)
      y.segment<6>(6 * col_rows_[static_cast<size_t>(k)]) -= l_blocks_[static_cast<size_t>(k)] * yp;
  }
  for (int p = n_ - 1; p >= 0; --p) {
    Vec6 yp = y.segment<6>(6 * p);
    for (int k = col_start_[static_cast<size_t>(p)]; k < col_start_[static_cast<size_t>(p) + 1]; ++k)
      yp -= l_blocks_[static_cast<size_t>(k)].transpose() * y.segment<6>(6 * col_rows_[static_cast<size_t>(k)]);
    y.segment<6>(6 * p) = l_diag_[static_cast<size_t>(p)].triangularView<Eigen::Lower>().transpose().solve(yp);
  }
  for (int p = 0; p < n_; ++p) b.segment<6>(6 * perm_[static_cast<size_t>(p)]) = y.segment<6>(6 * p);
}

}  // namespace rekon::optimiser::detail
