#include "video_writer.h"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

extern char** environ;

namespace farm::tools {

namespace fs = std::filesystem;

namespace {

// What of ffmpeg's log an error quotes (its last lines say what went wrong).
constexpr size_t kLogTailBytes = 2000;

std::string lower_extension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

}  // namespace

VideoKind video_kind(const std::string& path) {
  if (path.empty()) throw std::invalid_argument("--out is empty");
  if (path.back() == '/' || fs::is_directory(path)) return VideoKind::kPngFolder;
  const std::string ext = lower_extension(path);
  if (ext == ".mp4") return VideoKind::kMp4;
  if (ext == ".gif") return VideoKind::kGif;
  throw std::invalid_argument(
      "--out " + path + ": cannot tell what to write from " +
      (ext.empty() ? std::string("a path without an extension") : "the extension '" + ext + "'") +
      "; use FILE.mp4, FILE.gif or a folder ending in '/' for PNG frames");
}

std::string find_ffmpeg(const std::string& name) {
  if (name.empty()) throw std::invalid_argument("--ffmpeg is empty");
  if (name.find('/') != std::string::npos) {
    if (access(name.c_str(), X_OK) != 0 || fs::is_directory(name))
      throw std::runtime_error("ffmpeg program " + name + " is not an executable file");
    return name;
  }
  const char* path = std::getenv("PATH");
  std::string dirs = path ? path : "";
  std::stringstream ss(dirs);
  std::string dir;
  while (std::getline(ss, dir, ':')) {
    if (dir.empty()) continue;
    const fs::path candidate = fs::path(dir) / name;
    if (access(candidate.c_str(), X_OK) == 0 && !fs::is_directory(candidate)) return candidate.string();
  }
  throw std::runtime_error("ffmpeg not found: no executable '" + name + "' on PATH (" + dirs +
                           "); install Debian's ffmpeg package (deploy/install-deps.sh) or name one with --ffmpeg");
}

VideoWriter::VideoWriter(const std::string& path, int width, int height, int fps, const std::string& ffmpeg)
    : path_(path), kind_(video_kind(path)), frame_bytes_(size_t(width) * height * 3) {
  if (width <= 0 || height <= 0 || fps <= 0) throw std::invalid_argument("VideoWriter: bad frame size or rate");
  if (kind_ == VideoKind::kMp4 && (width % 2 || height % 2))
    throw std::invalid_argument("an MP4 (yuv420p) needs an even width and height, got " + std::to_string(width) + "x" +
                                std::to_string(height));
  // The output first: an unwritable one is named before any frame is rendered.
  std::error_code ec;
  if (kind_ == VideoKind::kPngFolder) {
    fs::create_directories(path, ec);
    if (ec) throw std::runtime_error("cannot write --out " + path + ": cannot make the folder: " + ec.message());
    const fs::path probe = fs::path(path) / ".farm-play-probe";
    const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0) throw std::runtime_error("cannot write --out " + path + ": " + std::strerror(errno));
    ::close(fd);
    fs::remove(probe, ec);
    target_ = (fs::absolute(path) / "frame_%06d.png").string();
  } else {
    const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT, 0644);
    if (fd < 0) throw std::runtime_error("cannot write --out " + path + ": " + std::strerror(errno));
    ::close(fd);
    target_ = fs::absolute(path).string();
  }
  // An absolute path starts with '/', so ffmpeg never reads a "name:" prefix as a protocol.
  std::string pattern = target_;
  if (kind_ == VideoKind::kPngFolder) {
    // '%' in the folder's name would be read as part of the frame number pattern.
    const std::string folder = fs::absolute(path).string();
    std::string escaped;
    for (char c : folder) escaped += c == '%' ? std::string("%%") : std::string(1, c);
    pattern = (fs::path(escaped) / "frame_%06d.png").string();
  }

  std::vector<std::string> args = {ffmpeg,
                                   "-hide_banner",
                                   "-loglevel",
                                   "error",
                                   "-y",
                                   "-f",
                                   "rawvideo",
                                   "-pix_fmt",
                                   "rgb24",
                                   "-s",
                                   std::to_string(width) + "x" + std::to_string(height),
                                   "-r",
                                   std::to_string(fps),
                                   "-i",
                                   "pipe:0"};
  switch (kind_) {
    case VideoKind::kMp4:
      args.insert(args.end(), {"-c:v", "libx264", "-preset", "veryfast", "-crf", "23", "-pix_fmt", "yuv420p",
                               "-movflags", "+faststart", "-f", "mp4", pattern});
      break;
    case VideoKind::kGif:
      // One palette for the whole clip (stats of what changes between frames), ordered dithering
      // (stable from frame to frame), and only the changed rectangle of each frame stored.
      args.insert(args.end(), {"-filter_complex",
                               "[0:v]split[a][b];[a]palettegen=stats_mode=diff[p];"
                               "[b][p]paletteuse=dither=bayer:bayer_scale=4:diff_mode=rectangle",
                               "-loop", "0", "-f", "gif", pattern});
      break;
    case VideoKind::kPngFolder:
      args.insert(args.end(), {"-start_number", "0", "-f", "image2", pattern});
      break;
  }

  char log_template[] = "/tmp/farm-play-ffmpeg-XXXXXX";
  const int log_fd = mkstemp(log_template);
  if (log_fd < 0) throw std::runtime_error(std::string("cannot make a log file for ffmpeg: ") + std::strerror(errno));
  log_path_ = log_template;
  int fds[2];
  if (pipe(fds) != 0) {
    ::close(log_fd);
    throw std::runtime_error(std::string("cannot make a pipe to ffmpeg: ") + std::strerror(errno));
  }
  // A dead ffmpeg makes write() fail with EPIPE (reported with its log), not kill this process.
  signal(SIGPIPE, SIG_IGN);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, fds[0], 0);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_adddup2(&actions, log_fd, 2);
  posix_spawn_file_actions_addclose(&actions, fds[1]);
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  const int rc = posix_spawn(&child_, ffmpeg.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(fds[0]);
  ::close(log_fd);
  if (rc != 0) {
    ::close(fds[1]);
    child_ = -1;
    abandon();
    throw std::runtime_error("cannot start " + ffmpeg + ": " + std::strerror(rc));
  }
  pipe_ = fds[1];
  fcntl(pipe_, F_SETFD, FD_CLOEXEC);
}

VideoWriter::~VideoWriter() {
  if (!finished_) abandon();
  if (!log_path_.empty()) unlink(log_path_.c_str());
}

std::string VideoWriter::ffmpeg_log() const {
  std::ifstream in(log_path_);
  std::stringstream ss;
  ss << in.rdbuf();
  std::string log = ss.str();
  if (log.size() > kLogTailBytes) log = "..." + log.substr(log.size() - kLogTailBytes);
  while (!log.empty() && (log.back() == '\n' || log.back() == ' ')) log.pop_back();
  return log.empty() ? "(ffmpeg printed nothing)" : log;
}

void VideoWriter::abandon() {
  if (pipe_ >= 0) ::close(pipe_);
  pipe_ = -1;
  if (child_ > 0) {
    kill(child_, SIGTERM);
    int status = 0;
    waitpid(child_, &status, 0);
    child_ = -1;
  }
  std::error_code ec;
  if (kind_ != VideoKind::kPngFolder && !target_.empty()) fs::remove(target_, ec);
  finished_ = true;
}

void VideoWriter::write(const unsigned char* rgb) {
  if (finished_ || pipe_ < 0) throw std::logic_error("VideoWriter::write after finish");
  size_t done = 0;
  while (done < frame_bytes_) {
    const ssize_t n = ::write(pipe_, rgb + done, frame_bytes_ - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = errno;
      ::close(pipe_);
      pipe_ = -1;
      int status = 0;
      if (child_ > 0) waitpid(child_, &status, 0);
      child_ = -1;
      const std::string log = ffmpeg_log();
      abandon();
      throw std::runtime_error("ffmpeg stopped reading frames (" + std::string(std::strerror(err)) + ") writing " +
                               path_ + ": " + log);
    }
    done += size_t(n);
  }
  ++frames_;
}

void VideoWriter::finish() {
  if (finished_) return;
  ::close(pipe_);
  pipe_ = -1;
  int status = 0;
  while (waitpid(child_, &status, 0) < 0 && errno == EINTR) {
  }
  child_ = -1;
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    const std::string how = WIFEXITED(status) ? "exited with status " + std::to_string(WEXITSTATUS(status))
                                              : "was killed by signal " + std::to_string(WTERMSIG(status));
    const std::string log = ffmpeg_log();
    abandon();
    throw std::runtime_error("ffmpeg " + how + " writing " + path_ + ": " + log);
  }
  finished_ = true;
}

}  // namespace farm::tools
