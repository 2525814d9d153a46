// A participant's name under DDS Security: the CN of its certificate, read by a worker from its own
// cert.pem and by the learner from the identity token (dds.cert.sn) in a remote participant's
// discovery data. Both must give the same name for a certificate deploy/make-pki.sh made.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include "dds.h"

using farm::dds::certificate_name;
using farm::dds::common_name_of_subject;

TEST(CertificateName, SubjectFormsOfTheIdentityToken) {
  // Fast DDS 2.9.1 puts OpenSSL's one-line form in the token (seen on the wire of a secured farm).
  EXPECT_EQ(common_name_of_subject("/O=rollout-farm/CN=w1"), "w1");
  EXPECT_EQ(common_name_of_subject("/CN=host-b-1/O=rollout-farm"), "host-b-1");
  EXPECT_EQ(common_name_of_subject("/O=rollout-farm/CN=farm CA"), "farm CA");
  EXPECT_EQ(common_name_of_subject("CN=w1,O=rollout-farm"), "w1");
  EXPECT_EQ(common_name_of_subject("CN=a\\,b,O=rollout-farm"), "a,b");
  EXPECT_EQ(common_name_of_subject("CN=w\\31,O=x"), "w1");
  // No CN, two CNs, or no subject: no name, so nothing is accepted in its name.
  EXPECT_EQ(common_name_of_subject("/O=rollout-farm"), "");
  EXPECT_EQ(common_name_of_subject("/CN=w1/CN=w2"), "");
  EXPECT_EQ(common_name_of_subject("CN=w1,CN=w2"), "");
  EXPECT_EQ(common_name_of_subject(""), "");
  EXPECT_EQ(common_name_of_subject("w1"), "");
}

TEST(CertificateName, WorkerCertificateFromMakePki) {
  char tmpl[] = "/tmp/farm-cert-XXXXXX";
  ASSERT_NE(mkdtemp(tmpl), nullptr);
  const std::string d = tmpl;
  const std::string cmd = "bash " + std::string(FARM_SOURCE_DIR) + "/deploy/make-pki.sh " + d +
                          "/pki worker:w1 worker:host-b-2 > " + d + "/pki.log 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  EXPECT_EQ(certificate_name(d + "/pki/w1"), "w1");
  EXPECT_EQ(certificate_name(d + "/pki/host-b-2"), "host-b-2");
  // A certificate with two CNs names no one; a missing file and a file that is no certificate are named.
  std::filesystem::create_directories(d + "/two");
  const std::string two = "openssl req -x509 -nodes -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -keyout " + d +
                          "/two/key.pem -out " + d + "/two/cert.pem -subj '/O=x/CN=w1/CN=w2' -days 1 >> " + d +
                          "/pki.log 2>&1";
  ASSERT_EQ(std::system(two.c_str()), 0) << two;
  try {
    certificate_name(d + "/two");
    ADD_FAILURE() << "a certificate with two CNs gave a name";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("no single common name"), std::string::npos) << e.what();
  }
  try {
    certificate_name(d + "/nowhere");
    ADD_FAILURE() << "a missing cert.pem was read";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(d + "/nowhere/cert.pem"), std::string::npos) << e.what();
  }
  std::filesystem::create_directories(d + "/bad");
  std::ofstream(d + "/bad/cert.pem") << "not a certificate\n";
  try {
    certificate_name(d + "/bad");
    ADD_FAILURE() << "a file without a certificate was read";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("holds no PEM certificate"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(d);
}
