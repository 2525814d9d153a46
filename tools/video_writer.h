// Video files through ffmpeg: raw RGB frames piped into an ffmpeg child process, which writes an
// MP4 (H.264, yuv420p), an animated GIF (its own palette, looping) or numbered PNG frames in a
// folder, chosen by the output path.
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <string>
#include <vector>

namespace farm::tools {

enum class VideoKind { kMp4, kGif, kPngFolder };

// .mp4 and .gif by extension; a path ending in '/' or an existing folder: PNG frames in it.
// Throws std::invalid_argument naming the path and the kinds there are.
VideoKind video_kind(const std::string& path);

// The ffmpeg program: `name` when it holds a '/', else the first executable `name` on PATH.
// Throws std::runtime_error saying where it looked and where ffmpeg comes from.
std::string find_ffmpeg(const std::string& name);

class VideoWriter {
 public:
  // Checks that the output can be written (a file is created, a folder made), then starts ffmpeg.
  // Throws std::runtime_error naming the path or ffmpeg's failure.
  VideoWriter(const std::string& path, int width, int height, int fps, const std::string& ffmpeg);
  ~VideoWriter();  // an unfinished video is abandoned: ffmpeg ended, the partial output removed
  VideoWriter(const VideoWriter&) = delete;
  VideoWriter& operator=(const VideoWriter&) = delete;

  // One frame: width x height x 3 bytes, RGB, top row first. Throws std::runtime_error with
  // ffmpeg's own words when it stopped reading.
  void write(const unsigned char* rgb);
  // Ends the input and waits for ffmpeg; throws std::runtime_error with its words on a failure.
  void finish();
  int64_t frames() const { return frames_; }
  VideoKind kind() const { return kind_; }
  // Where the frames went: the file, or the folder's "frame_%06d.png" pattern.
  const std::string& target() const { return target_; }

 private:
  std::string ffmpeg_log() const;
  void abandon();

  std::string path_, target_, log_path_;
  VideoKind kind_;
  size_t frame_bytes_;
  int pipe_ = -1;
  pid_t child_ = -1;
  int64_t frames_ = 0;
  bool finished_ = false;
};

}  // namespace farm::tools
