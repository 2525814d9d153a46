// Batches held until their worker session is announced (IngestThread). A stream opens only from
// the participant whose heartbeat announced its session (Ingest::set_announcer); a session number
// is random and first read off the bus in its worker's own heartbeat, so a participant that copies
// it and writes first (a stream thief) is refused. That heartbeat can reach the learner after the
// copy's batch: a learner whose reader matched the worker's heartbeat writer after the worker's
// first beat hears the next one, a second later, while a thief that heard the first has written
// already. So the first batch of a session not announced yet is held, and every later batch of
// that session with it, in the order taken, until the announcement is heard (then each is decided
// against it: the thief's refused, the worker's taken) or `seconds` have passed since the first
// was held (then they are decided without it: the session opens from its first writer). The ingest
// goes on with other streams meanwhile.
//
// Bounded: at most `per_participant` batches of one participant and `bytes` in all are held. A
// batch past either bound is not held; one of a session on hold first releases that session (its
// batches decided at once, in order), so nothing is refused for the room and the order holds.
#pragma once

#include <cstddef>
#include <deque>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace farm {

template <class Key, class Item>
class FirstBatchHold {
 public:
  struct Limits {
    double seconds = 3.0;          // a worker beats once a second: two beats missed and some
    size_t per_participant = 256;  // batches of one participant on hold, all sessions
    size_t bytes = size_t(64) << 20;
  };
  explicit FirstBatchHold(Limits limits = Limits()) : limits_(limits) {}

  bool empty() const { return order_.empty(); }
  bool holds(const Key& key) const { return held_.count(key) > 0; }
  size_t batches() const { return batches_; }
  size_t bytes() const { return bytes_; }
  size_t sessions() const { return order_.size(); }

  // Holds item under key, taken now; false (item untouched) when the participant's or the total's
  // bound leaves no room.
  bool hold(const Key& key, const std::string& participant, size_t item_bytes, double now, Item& item) {
    auto p = per_participant_.find(participant);
    if ((p != per_participant_.end() && p->second >= limits_.per_participant) || bytes_ + item_bytes > limits_.bytes)
      return false;
    auto [it, fresh] = held_.try_emplace(key);
    if (fresh) {
      it->second.since = now;
      order_.push_back(key);
    }
    it->second.items.push_back(Held{std::move(item), participant, item_bytes});
    ++per_participant_[participant];
    bytes_ += item_bytes;
    ++batches_;
    return true;
  }

  // Hands the batches of every session announced now (announced(key) true) or held `seconds` or
  // longer to take(key, item), session by session in the order they were first held and each
  // session's in the order taken; returns how many.
  template <class Announced, class Take>
  size_t release(double now, Announced announced, Take take) {
    size_t n = 0;
    for (size_t i = 0; i < order_.size();) {
      const Key key = order_[i];
      if (now - held_.at(key).since >= limits_.seconds || announced(key)) {
        n += release_at(i, take);
      } else {
        ++i;
      }
    }
    return n;
  }

  // Hands key's batches to take now, in order (no room for its next one); returns how many.
  template <class Take>
  size_t release(const Key& key, Take take) {
    for (size_t i = 0; i < order_.size(); ++i)
      if (order_[i] == key) return release_at(i, take);
    return 0;
  }

 private:
  struct Held {
    Item item;
    std::string participant;
    size_t bytes;
  };
  struct Session {
    double since = 0;
    std::vector<Held> items;
  };

  template <class Take>
  size_t release_at(size_t i, Take take) {
    const Key key = order_[i];
    auto node = held_.extract(key);
    order_.erase(order_.begin() + std::ptrdiff_t(i));
    for (Held& h : node.mapped().items) {
      auto p = per_participant_.find(h.participant);
      if (--p->second == 0) per_participant_.erase(p);
      bytes_ -= h.bytes;
      --batches_;
    }
    // Counts settled first: take may hold again (under another key).
    for (Held& h : node.mapped().items) take(key, h.item);
    return node.mapped().items.size();
  }

  Limits limits_;
  std::map<Key, Session> held_;
  std::deque<Key> order_;  // sessions, first held first
  std::map<std::string, size_t> per_participant_;
  size_t bytes_ = 0, batches_ = 0;
};

}  // namespace farm
