#include "trust.h"

#include "dds.h"

#include <openssl/bio.h>
#include <openssl/pem.h>
#include <openssl/pkcs7.h>
#include <openssl/x509.h>
#include <openssl/x509_vfy.h>
#include <tinyxml2.h>

#include <cctype>
#include <cstdio>
#include <memory>

namespace farm::dds {

namespace {

bool valid_name(const std::string& n) {
  if (n.empty()) return false;
  for (char c : n)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-')) return false;
  return true;
}

const char* kWorkerPrefix = "worker/";

template <class T, void (*F)(T*)>
struct Deleter {
  void operator()(T* p) const { F(p); }
};
using BioPtr = std::unique_ptr<BIO, Deleter<BIO, BIO_free_all>>;
using X509Ptr = std::unique_ptr<X509, Deleter<X509, X509_free>>;
using StorePtr = std::unique_ptr<X509_STORE, Deleter<X509_STORE, X509_STORE_free>>;
using Pkcs7Ptr = std::unique_ptr<PKCS7, Deleter<PKCS7, PKCS7_free>>;
using CrlPtr = std::unique_ptr<X509_CRL, Deleter<X509_CRL, X509_CRL_free>>;

}  // namespace

std::string worker_partition(const std::string& name) { return kWorkerPrefix + name; }

std::string worker_of_partitions(const std::vector<std::string>& partitions) {
  if (partitions.size() != 1) return "";
  const std::string& p = partitions[0];
  if (p.compare(0, 7, kWorkerPrefix) != 0) return "";
  const std::string name = p.substr(7);
  return valid_name(name) ? name : "";
}

std::string partitions_text(const std::vector<std::string>& partitions) {
  std::string s;
  for (const auto& p : partitions) s += (s.empty() ? "" : ";") + p;
  return "[" + s + "]";
}

void WriterNames::writer(const eprosima::fastrtps::rtps::GUID_t& guid, const std::vector<std::string>& partitions,
                         Event event) {
  std::lock_guard<std::mutex> lk(mu_);
  auto it = writers_.find(guid);
  if (event == Event::kRemoved) {
    if (it != writers_.end()) it->second.gone = true;  // kept: its last samples may still wait in a reader
    return;
  }
  if (it != writers_.end()) {
    // Announced again (QoS changed, or a repeated discovery): the name stays the first one, and a
    // writer whose partitions moved names no one from now on.
    Entry& e = it->second;
    if (e.taint.empty() && partitions != e.partitions)
      e.taint = "its partitions changed after discovery from " + partitions_text(e.partitions) + " to " +
                partitions_text(partitions);
    return;
  }
  if (writers_.size() >= kMaxWriters) {
    // Departed writers go first, then the oldest: an evicted writer names no one (refused, never renamed).
    auto victim = writers_.end();
    for (auto j = writers_.begin(); j != writers_.end(); ++j) {
      if (victim == writers_.end() || (j->second.gone && !victim->second.gone) ||
          (j->second.gone == victim->second.gone && j->second.order < victim->second.order))
        victim = j;
    }
    writers_.erase(victim);
  }
  Entry& e = writers_[guid];
  e.partitions = partitions;
  e.name = worker_of_partitions(partitions);
  e.order = next_order_++;
  // A first announcement already marked as a change: the writer was matched before this process
  // knew its partitions, so the first ones are unknown.
  if (event == Event::kChanged) e.taint = "its first announcement here was a change of partitions";
}

std::string WriterNames::name_of(const eprosima::fastrtps::rtps::GUID_t& guid, std::string* why) const {
  std::lock_guard<std::mutex> lk(mu_);
  auto it = writers_.find(guid);
  std::string reason;
  if (it == writers_.end())
    reason = "its writer was not discovered";
  else if (!it->second.taint.empty())
    reason = it->second.taint;
  else if (it->second.name.empty())
    reason = "its writer is in partitions " + partitions_text(it->second.partitions) + ", not in one worker/<name>";
  else
    return it->second.name;
  if (why) *why = reason;
  return "";
}

std::string load_worker_grants(const std::string& permissions_p7s, const std::string& ca_pem,
                               std::set<std::string>& names) {
  BioPtr ca_in(BIO_new_file(ca_pem.c_str(), "r"));
  if (!ca_in) return "cannot read " + ca_pem;
  X509Ptr ca(PEM_read_bio_X509(ca_in.get(), nullptr, nullptr, nullptr));
  if (!ca) return ca_pem + " holds no PEM certificate";
  StorePtr store(X509_STORE_new());
  if (!store || X509_STORE_add_cert(store.get(), ca.get()) != 1) return "cannot make a certificate store";
  BioPtr in(BIO_new_file(permissions_p7s.c_str(), "r"));
  if (!in) return "cannot read " + permissions_p7s;
  BIO* content = nullptr;
  Pkcs7Ptr p7(SMIME_read_PKCS7(in.get(), &content));
  BioPtr content_owner(content);
  if (!p7) return permissions_p7s + " is not an S/MIME signed document";
  BioPtr out(BIO_new(BIO_s_mem()));
  if (PKCS7_verify(p7.get(), nullptr, store.get(), content, out.get(), PKCS7_TEXT) != 1)
    return permissions_p7s + " is not signed by the permissions CA " + ca_pem;
  char* data = nullptr;
  const long len = BIO_get_mem_data(out.get(), &data);
  tinyxml2::XMLDocument doc;
  if (doc.Parse(data, size_t(len)) != tinyxml2::XML_SUCCESS) return permissions_p7s + " holds no valid XML";
  const tinyxml2::XMLElement* perms = doc.RootElement() ? doc.RootElement()->FirstChildElement("permissions") : nullptr;
  if (!perms) return permissions_p7s + " has no <permissions>";
  std::set<std::string> got;
  for (auto* g = perms->FirstChildElement("grant"); g; g = g->NextSiblingElement("grant")) {
    const auto* sn = g->FirstChildElement("subject_name");
    const std::string name = common_name_of_subject(sn && sn->GetText() ? sn->GetText() : "");
    if (name.empty()) continue;
    bool writes_own = false;
    for (auto* r = g->FirstChildElement("allow_rule"); r && !writes_own; r = r->NextSiblingElement("allow_rule"))
      for (auto* p = r->FirstChildElement("publish"); p && !writes_own; p = p->NextSiblingElement("publish"))
        for (auto* ps = p->FirstChildElement("partitions"); ps && !writes_own;
             ps = ps->NextSiblingElement("partitions"))
          for (auto* q = ps->FirstChildElement("partition"); q && !writes_own; q = q->NextSiblingElement("partition"))
            writes_own = q->GetText() && worker_partition(name) == q->GetText();
    if (writes_own) got.insert(name);
  }
  names.swap(got);
  return "";
}

std::string crl_problem(const std::string& crl_pem) {
  BioPtr in(BIO_new_file(crl_pem.c_str(), "r"));
  if (!in) return "cannot read " + crl_pem;
  CrlPtr crl(PEM_read_bio_X509_CRL(in.get(), nullptr, nullptr, nullptr));
  if (!crl) return crl_pem + " holds no PEM certificate revocation list";
  if (X509_cmp_current_time(X509_CRL_get0_lastUpdate(crl.get())) > 0)
    return "the revocation list " + crl_pem + " is not valid yet by this host's clock";
  const ASN1_TIME* next = X509_CRL_get0_nextUpdate(crl.get());
  if (next && X509_cmp_current_time(next) < 0)
    return "the revocation list " + crl_pem +
           " has expired (its next update is past): make a new one with deploy/make-pki.sh OUTDIR --revoke";
  return "";
}

}  // namespace farm::dds
