// The engine's public face: everything a program outside engine/ (the server, tools, other embedders) may
// use. Include this header, not the engine's other headers; the rest of engine/ (audio/, nn/, model/, vq/,
// runtime/internal/) is its implementation, for the engine itself, its tests and its benchmarks. The
// engine knows nothing of networks: no gRPC, protobuf, HTTP or JSON-over-the-wire here (JSON appears only
// as the dance-motion/v1 file format and the weights file's header).
//
//   - Model, LoadModel (runtime/model.h): a validated .dncw file, immutable, shared by sessions.
//   - Session, StepBatch, SessionOptions, SessionSnapshot (runtime/session.h): one performer's stream,
//     audio in, pose frames out, snapshot/restore; many sessions per weight pass.
//   - SamplingOptions (nn/sampling.h): temperature, top-k/top-p, guidance, music guidance, locks.
//   - StyleMix, ResolveStyle (runtime/style_mix.h): named style weights.
//   - Controls, MotionTrack, TrajectoryPoint (runtime/controls.h): seed motion, given halves, keyframes,
//     inpainting, trajectory; ReadMotionFile, ReadTrajectoryFile, ReadMaskFile (runtime/motion_io.h) read
//     their files; ControlSpec, BuildControls (runtime/control_spec.h): controls as a request states them
//     (files' text or poses, mask spans, a path) into Controls.
//   - PoseFrame (runtime/pose_frame.h): one emitted frame (positions, rotations, codes).
//   - WriteDanceJson, WriteBvh (runtime/dance_writer.h): whole-dance files.
//   - audio::DecodeAudioFile (audio/decoder.h): audio files to PCM.
//   - SgmdModel, GenerateSgmdDance (diffusion/): the motion-diffusion editor, a whole dance at once
//     (docs/diffusion.md).
//
// Usage:
//   #include "engine/engine.h"
//   absl::StatusOr<std::shared_ptr<const dance::engine::Model>> model = dance::engine::LoadModel(path);
//   dance::engine::SessionOptions options;  options.input_sample_rate = 44100;  options.input_channels = 2;
//   auto session = dance::engine::Session::Create(*model, options);
//   (*session)->PushAudio(pcm);  while ((*session)->StepsReady() > 0) (*session)->Step();
//   std::vector<dance::engine::PoseFrame> frames;  (*session)->PopFrames(&frames);
//
// Errors are absl::Status values throughout (InvalidArgument for bad input, NotFound / DataLoss for
// files, FailedPrecondition for calls out of order); nothing throws across this boundary. Thread safety is
// stated per class: a Model is shared read-only, a Session has one owner at a time.
#ifndef DANCE_ENGINE_ENGINE_H_
#define DANCE_ENGINE_ENGINE_H_

#include "engine/audio/decoder.h"
#include "engine/diffusion/sgmd_dance.h"
#include "engine/diffusion/sgmd_model.h"
#include "engine/nn/sampling.h"
#include "engine/runtime/control_spec.h"
#include "engine/runtime/controls.h"
#include "engine/runtime/dance_writer.h"
#include "engine/runtime/model.h"
#include "engine/runtime/motion_io.h"
#include "engine/runtime/pose_frame.h"
#include "engine/runtime/session.h"
#include "engine/runtime/style_mix.h"

#endif  // DANCE_ENGINE_ENGINE_H_
