// Prints how many elements an XML file (the first argument) holds.
#include <cstdio>
#include <functional>

#include "tinyxml2.h"

int main(int argc, char ** argv)
{
  if (argc != 2) {
    std::fprintf(stderr, "usage: xml_count FILE\n");
    return 2;
  }
  tinyxml2::XMLDocument document;
  if (document.LoadFile(argv[1]) != tinyxml2::XML_SUCCESS) {
    std::fprintf(stderr, "xml_count: %s\n", document.ErrorStr());
    return 1;
  }
  std::function<int(const tinyxml2::XMLElement *)> count = [&count](const tinyxml2::XMLElement * element) {
      int total = 0;
      for (; element != nullptr; element = element->NextSiblingElement()) {
        total += 1 + count(element->FirstChildElement());
      }
      return total;
    };
  std::printf("%d elements\n", count(document.FirstChildElement()));
  return 0;
}
