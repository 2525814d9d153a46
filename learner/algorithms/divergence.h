// Divergence guard for the learners: a NaN or infinite loss means the networks are gone, and
// nothing they produce may reach the workers or a checkpoint.
#pragma once

#include <cstdint>
#include <initializer_list>
#include <string>
#include <utility>
#include <vector>

namespace farm {

// Throws std::runtime_error naming the algorithm, the update (or fit) and every figure when one
// of them is NaN or infinite. The learner then stops; the last checkpoint written stays as it was.
void require_finite_update(const std::string& algorithm, int64_t update,
                           std::initializer_list<std::pair<const char*, double>> figures);
void require_finite_update(const std::string& algorithm, int64_t update,
                           const std::vector<std::pair<std::string, double>>& figures);

}  // namespace farm
