// Scratch activations for one batched step of the sequence model, sized for up to `capacity` lanes.
//
// Blocks use the leftmost columns they need (`.leftCols(n)`), so a workspace serves any batch up to its
// capacity without allocating. Grow it with Reserve (allocates) outside the hot loop.
//
// Thread safety: none; one workspace per stepping thread.
#ifndef DANCE_ENGINE_MODEL_WORKSPACE_H_
#define DANCE_ENGINE_MODEL_WORKSPACE_H_

#include <algorithm>
#include <array>
#include <vector>

#include "Eigen/Core"
#include "engine/model/seq_config.h"

namespace dance::engine {

struct SequenceState;

struct Workspace {
  int capacity = 0;       // lanes
  Eigen::MatrixXf x;      // (d, 3L) residual stream, column 3b + s
  Eigen::MatrixXf h;      // (d, 3L) normalised input
  Eigen::MatrixXf zg;     // (2d, 3L) TGCA [SiLU(W_in h); SiLU(W_g h)]
  Eigen::MatrixXf qkv;    // (3d, 3L)
  Eigen::MatrixXf attn;   // (d, 3L) attention output (gated in place)
  Eigen::MatrixXf delta;  // (d, 3L) a block's residual update
  Eigen::MatrixXf gate;   // (d_ff, 3L) GatedMLP scratch
  Eigen::MatrixXf up;     // (d_ff, 3L)
  Eigen::MatrixXf scores; // (3W, 3) one lane's attention probabilities
  Eigen::MatrixXf style;  // (d, L) one block's style factors for every lane
  Eigen::MatrixXf music;  // (4F, L) normalised music tokens
  Eigen::MatrixXf pre;    // (P, L)
  Eigen::MatrixXf stream_x;   // (d, L) one stream's tokens, contiguous
  Eigen::MatrixXf stream_h;   // (d, L)
  Eigen::MatrixXf xz;         // (2 d_inner, L) Mamba in_proj output
  Eigen::MatrixXf conv_out;   // (d_inner, L)
  Eigen::MatrixXf dbc;        // (dt_rank + 2 d_state, L)
  Eigen::MatrixXf dt;         // (d_inner, L)
  Eigen::MatrixXf y;          // (d_inner, L)
  Eigen::ArrayXf dtx;         // (d_inner) one lane's dt * x
  Eigen::MatrixXf logits_u;   // (K, L)
  Eigen::MatrixXf logits_l;   // (K, L)
  std::vector<SequenceState*> states;  // the lanes of the current step
  std::array<int, 9> dims_{};          // the sizes the matrices were made for

  // Sizes for `lanes` lanes of a model with config `c`; reallocates when the batch grows or the model's
  // sizes differ from the last call's (one workspace may serve several models).
  void Reserve(const SeqConfig& c, int lanes) {
    const std::array<int, 9> dims = {c.d_model, c.d_inner(), c.d_state, c.dt_rank(), c.d_ff(),
                                     c.attn_window, c.music_dim(), c.pre_dim, c.codebook_size};
    const bool same_model = dims == dims_;
    if (lanes <= capacity && same_model) return;
    dims_ = dims;
    capacity = std::max(lanes, same_model ? capacity : 0);
    const int d = c.d_model, t = 3 * lanes, di = c.d_inner();
    x.resize(d, t);
    h.resize(d, t);
    zg.resize(2 * d, t);
    qkv.resize(3 * d, t);
    attn.resize(d, t);
    delta.resize(d, t);
    gate.resize(c.d_ff(), t);
    up.resize(c.d_ff(), t);
    scores.resize(3 * c.attn_window, 3);
    style.resize(d, lanes);
    music.resize(c.music_dim(), lanes);
    pre.resize(c.pre_dim, lanes);
    stream_x.resize(d, lanes);
    stream_h.resize(d, lanes);
    xz.resize(2 * di, lanes);
    conv_out.resize(di, lanes);
    dbc.resize(c.dt_rank() + 2 * c.d_state, lanes);
    dt.resize(di, lanes);
    y.resize(di, lanes);
    dtx.resize(di);
    logits_u.resize(c.codebook_size, lanes);
    logits_l.resize(c.codebook_size, lanes);
    states.reserve(lanes);
  }
};

}  // namespace dance::engine

#endif  // DANCE_ENGINE_MODEL_WORKSPACE_H_
