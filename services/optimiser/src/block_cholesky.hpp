#pragma once
// Sparse Cholesky factorisation of a symmetric positive-definite matrix made
// of 6x6 blocks (a pose graph's normal equations: one block row per keyframe,
// one off-diagonal block per linked pair). Working on whole blocks with
// fixed-size Eigen kernels beats a scalar sparse Cholesky (CHOLMOD on a
// generic BLAS, Eigen's simplicial LLT) by about 3x on these graphs, and the
// symbolic analysis (AMD ordering, the pattern of L) is kept for as long as
// the pattern does not change.
#include <Eigen/Core>
#include <cstdint>
#include <utility>
#include <vector>

namespace rekon::optimiser::detail {

using Block6 = Eigen::Matrix<double, 6, 6>;

class BlockCholesky {
 public:
  // The pattern: `n` block rows and the unordered pairs (i, j), i != j, with
  // a nonzero off-diagonal block (duplicates allowed). Computes a fill-reducing
  // ordering and the block pattern of L.
  void analyse(int n, const std::vector<std::pair<int, int>>& pairs);
  int size() const { return n_; }
  // Index of the off-diagonal block (i, j) in offDiagonal() (either order);
  // -1 when the pair is not in the pattern.
  int pairIndex(int i, int j) const;

  // The matrix: diagonal blocks and one block per pair index, A(i, j) for the
  // pair as stored (pairRows()[k] = (i, j); A(j, i) is its transpose).
  std::vector<Block6>& diagonal() { return diag_; }
  std::vector<Block6>& offDiagonal() { return off_; }
  const std::vector<std::pair<int, int>>& pairRows() const { return pair_rows_; }
  void setZero();

  // Factorises diag(A) * (1 + damping) + off(A); false when not positive definite.
  bool factorize(double damping = 0.0);
  // Solves A x = b in place (b has 6 n entries).
  void solve(Eigen::VectorXd& b) const;

  // Blocks in L (diagonal included), for the report.
  int64_t factorBlocks() const { return static_cast<int64_t>(l_blocks_.size()) + n_; }

 private:
  // analyse(), step by step; each fills the members it names.
  // pair_rows_ and pair_keys_ / pair_key_index_, without duplicates.
  void keepUniquePairs(const std::vector<std::pair<int, int>>& pairs);
  // perm_ and iperm_.
  void orderToReduceFill(const std::vector<std::vector<int>>& adjacency);
  // col_start_ and col_rows_ (the symbolic factorisation).
  void analyseFactorPattern(const std::vector<std::vector<int>>& adjacency);
  // pair_slot_ and pair_transposed_.
  void placePairBlocks();

  int n_ = 0;
  std::vector<int> perm_, iperm_;  // new position of old row i: iperm_[i]; old row at new position p: perm_[p]
  // Column p of L (new order): rows col_rows_[col_start_[p] .. col_start_[p+1]), ascending, all > p.
  std::vector<int> col_start_, col_rows_;
  std::vector<Block6> l_blocks_;  // parallel to col_rows_
  std::vector<Block6> l_diag_;    // lower-triangular diagonal factors
  // Where each pair's block goes in L: index into l_blocks_ (the pair in new
  // order is (row > column); transposed when the stored orientation is the other one).
  std::vector<int> pair_slot_;
  std::vector<bool> pair_transposed_;
  std::vector<std::pair<int, int>> pair_rows_;
  std::vector<int64_t> pair_keys_;  // sorted (min << 32 | max) with the pair index
  std::vector<int> pair_key_index_;
  std::vector<Block6> diag_, off_;
};

}  // namespace rekon::optimiser::detail
