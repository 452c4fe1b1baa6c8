// validate: checks rendered Kubernetes manifests (helm template output on stdin) against the Kubernetes
// API types: every document is decoded strictly with client-go's scheme, so an unknown kind or apiVersion,
// a misspelt or misplaced field, a duplicate field or a value of the wrong type fails. (kubeconform needs
// its JSON schemas from GitHub at run time; the API types come from the Go module proxy, pinned in go.mod.)
//
//	helm template deploy/helm/dance | go run ./deploy/helm/validate
package main

import (
	"bufio"
	"bytes"
	"errors"
	"fmt"
	"io"
	"os"

	"k8s.io/apimachinery/pkg/runtime/serializer"
	utilyaml "k8s.io/apimachinery/pkg/util/yaml"
	"k8s.io/client-go/kubernetes/scheme"
)

func main() {
	decoder := serializer.NewCodecFactory(scheme.Scheme, serializer.EnableStrict).UniversalDeserializer()
	reader := utilyaml.NewYAMLReader(bufio.NewReader(os.Stdin))
	n, failed := 0, 0
	for {
		doc, err := reader.Read()
		if errors.Is(err, io.EOF) {
			break
		}
		if err != nil {
			fmt.Fprintf(os.Stderr, "validate: reading: %v\n", err)
			os.Exit(2)
		}
		if len(bytes.TrimSpace(doc)) == 0 || bytes.Equal(bytes.TrimSpace(doc), []byte("---")) {
			continue
		}
		n++
		obj, gvk, err := decoder.Decode(doc, nil, nil)
		if err != nil {
			failed++
			fmt.Fprintf(os.Stderr, "INVALID document %d: %v\n", n, err)
			continue
		}
		_ = obj
		fmt.Printf("valid   %s\n", gvk.String())
	}
	fmt.Printf("validate: %d documents, %d invalid\n", n, failed)
	if failed > 0 || n == 0 {
		os.Exit(1)
	}
}
